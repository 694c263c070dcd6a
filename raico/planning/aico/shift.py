"""One AICO / R-AICO run kept across receding-horizon ticks (Toussaint's aico.cpp ``shiftSolution``).

:class:`ShiftedAICO` owns one workspace for a window problem of ``H`` steps: the sweeps' arrays
(:class:`raico.planning.aico.sweeps.Sweeps`: forward and backward messages, beliefs, task messages, the
linearization), the trajectory and controller, the hard constraints' augmented Lagrangian (multipliers and
penalty) and R-AICO's ``alpha``. Each tick :meth:`ShiftedAICO.shift` moves all of them by one step (the
last step repeated, the backward message at the end kept zero), :meth:`ShiftedAICO.start_at` resets the
first belief to the measured state and rolls the shifted controller out from it, and
:meth:`ShiftedAICO.iterate` runs the fixed schedule's iterations: linearize at the trajectory (R-AICO's
regularization anchored there), sweep, roll the new controller out (controls clipped into their box).
The window's cost recorded is that of the trajectory the last iteration linearized at (its task rows give
the derivatives and the cost in one pass).

The sweeps are :class:`ShiftSweeps`: the linearization's loops compiled (the dynamics at every step and the
control Hessians' checks in one call, the boxes' augmented Lagrangian in ``box_al.c``), the model's compiled
rollout into work arrays, the control messages and the cost's task rows into kept buffers; the numbers are
those of ``Sweeps`` and the numpy boxes bit for bit (tests/planning/test_mpc_kernels.py). Work buffers are
allocated once; a tick allocates only small temporaries that live within it (the numpy assembly of the task
messages into strided views, views and scalars), see docs/mpc.md.

:class:`SplitTick` splits the tick into a feedback phase (``u = o_0 + O_0 x``, nothing allocated) and the
preparation of the next window from the model's prediction (Diehl's real-time iteration; ``MPC(..., split=True)``).
"""

from __future__ import annotations

import ctypes
import dataclasses
import math
import time
import weakref

import numpy as np

from raico.planning import kernels
from raico.planning.aico.bounds import hard_constraints
from raico.planning.aico.options import AICOOptions
from raico.planning.aico.solve import check_control_cost
from raico.planning.aico.sweeps import NumericalError, Sweeps
from raico.planning.constraints import AugmentedLagrangian, ControlBox, StateBox
from raico.planning.costs import ControlCost
from raico.planning.problem import Problem

_ADDRS: dict[int, tuple[weakref.ref, int]] = {}


def _addr(a: np.ndarray) -> int:
    """The data address of ``a`` (numpy's ``.ctypes.data`` costs a microsecond: taken once per array, while
    it lives; the workspace passes the same arrays every tick)."""
    hit = _ADDRS.get(id(a))
    if hit is None or hit[0]() is not a:
        if len(_ADDRS) > 256:
            _ADDRS.clear()
        hit = _ADDRS[id(a)] = (weakref.ref(a), a.ctypes.data)
    return hit[1]


def shift_rows(a: np.ndarray, scratch: np.ndarray, stop: int | None = None) -> None:
    """``a[t] = a[t+1]`` for ``t < stop - 1`` (default ``len(a)``; the row ``stop - 1`` kept: the last one
    repeated) in place, through ``scratch`` (at least ``a``'s size; numpy copies overlapping views through a
    fresh temporary otherwise)."""
    stop = a.shape[0] if stop is None else stop
    if stop < 2:
        return
    k = (stop - 1) * (a.size // a.shape[0])
    buf = scratch.reshape(-1)[:k].reshape((stop - 1, *a.shape[1:]))
    np.copyto(buf, a[1:stop])
    np.copyto(a[:stop - 1], buf)


class ShiftedAICO:
    """AICO / R-AICO with the fixed schedule on a window problem, its state carried across ticks.

    Args:
        window: the window problem (its ``x0`` array is the start; :meth:`start_at` writes it).
        opts: the options (``schedule`` must be ``"fixed"``; ``alpha`` shrinks by ``gamma`` per iteration
            over the ticks).

    Attributes:
        X, U, o, O: the current trajectory ``(H+1, n)``, controls ``(H, m)`` and controller.
        alpha: the regularization of the next iteration.
        sw: the sweeps (their arrays are shifted with the solution).
    """

    def __init__(self, window: Problem, opts: AICOOptions):
        if opts.schedule != "fixed":
            raise ValueError("the shifted workspace runs the fixed schedule")
        b = window.bounds
        self.problem, self.opts, self.alpha = window, opts, float(opts.alpha)
        self.efforts = b if b is not None and b.has_controls else None
        self.inner = window if self.efforts is None else dataclasses.replace(
            window, bounds=dataclasses.replace(b, u_lower=None, u_upper=None))
        check_control_cost(self.inner)
        self.sw = ShiftSweeps(self.inner, opts)
        T, n, m = window.T, window.n_x, window.n_u
        self.T, self.n, self.m = T, n, m
        self.X, self.U = np.tile(window.x0, (T + 1, 1)), np.zeros((T, m))
        self.o, self.O = np.zeros((T, m)), np.zeros((T, m, n))
        self._scratch = np.empty((T + 1) * max(n * (n + 1), (n + 1) * (m + n + 1), m * (n + 1)))
        self._sv = float(opts.start_variance)
        self._S0 = np.eye(n) / self._sv          # the start message's precision
        self.al: AugmentedLagrangian | None = None
        self._task_views: list | None = None
        self._moves: list | None = None   # (owner, name, array, dst, src, bytes) of the shift's moves
        self._al_built = False
        self._fast = None     # the compiled rollout's call (built at the first rollout), False: none
        self._box_work = np.empty((T, m), dtype=bool)
        self.solved = False
        self.cost = math.nan
        self.defer = False      # the split: the last iteration's rollout and multiplier step wait (settle)
        self.pending = False    # an iteration's rollout and multiplier step are waiting
        self.fb_o, self.fb_O = np.zeros(m), np.zeros((m, n))   # the controller's first step the feedback used
        box = (None, None) if self.efforts is None else (
            np.ascontiguousarray(self.efforts.u_lower, dtype=float), np.ascontiguousarray(self.efforts.u_upper, dtype=float))
        self._fb = (self.o[0], self.O[0], *box)

    # -- the shift
    def shift(self) -> None:
        """Everything by one step towards the start (aico.cpp's ``shiftSolution``): trajectory, controls,
        controller, forward and backward messages, beliefs, task messages, linearization, the constraints'
        multipliers; the last step repeated, the backward message at the end kept zero. Without relinearization
        in the sweeps (``theta = inf``) the messages, beliefs and linearization are written anew before anything
        reads them (the backward sweep starts from the zero end, the forward messages and beliefs are not
        computed): only the trajectory, controls, controller and multipliers move. A waiting rollout
        (:meth:`settle`) runs first."""
        if self.pending:
            self.settle()
        if self._moves is None or any(getattr(o, n) is not a for o, n, a, *_ in self._moves):
            self._moves = self._plan_moves()        # the first shift, or an array replaced since
        for *_, dst, src, nbytes in self._moves:
            ctypes.memmove(dst, src, nbytes)        # one overlapping move per array, no temporary
        if self.al is not None:
            for y in self.al.y:
                if y is not None:
                    shift_rows(y, self._scratch)

    def _targets(self) -> list[tuple[object, str, int | None]]:
        """The arrays the shift moves: ``(owner, attribute, rows moved or None: all)``."""
        sw = self.sw
        out: list[tuple[object, str, int | None]] = [(self, n, None) for n in ("X", "U", "o", "O")]
        if not sw.relocate:
            return out
        out += [(sw, n, None) for n in ("SA", "b", "RA", "Z", "_lx")]
        out.append((sw, "VA", self.T))            # VA[T] = 0 (the end)
        if sw.C.flags.writeable:                  # a time-varying linearization (an LTI one is shared by all steps)
            out.append((sw, "C", None))
        out.append((sw, "_Qbar", None))           # the marginals' buffer (where the steps' Qbar differ)
        return out

    def _plan_moves(self) -> list[tuple]:
        moves = []
        for owner, name, stop in self._targets():
            a = getattr(owner, name)
            if not a.flags.c_contiguous:
                raise AssertionError(f"{name} must be C-contiguous")
            rows = a.shape[0] if stop is None else stop
            row = a.strides[0]
            base = a.__array_interface__["data"][0]
            moves.append((owner, name, a, base, base + row, (rows - 1) * row))
        return moves

    def start_at(self, x: np.ndarray) -> bool:
        """The first belief reset to the measured state ``x (n,)`` (``x0`` and the start message), and the
        controller rolled out from it (controls clipped into their box) as the trajectory the next iteration
        linearizes at. Returns False (the trajectory unchanged) if that rollout is not finite. A waiting
        rollout (:meth:`settle`) runs first, from the start it was waiting for."""
        if self.pending:
            self.settle()
        self.problem.x0[:] = x
        sv, n, SA = self._sv, self.n, self.sw.SA
        np.copyto(SA[0, :, :n], self._S0)
        np.divide(x, sv, out=SA[0, :, n])
        if not self.solved:
            self.X[:] = x
            return True
        return self._rollout()

    def _rollout(self) -> bool:
        """The controller ``o, O`` rolled out from ``x0`` (``Problem.bounded_rollout``: controls clipped into their
        box, the controller made the consistent one where one was) into ``X, U``; False (nothing changed) if the
        rollout is not finite. The model's compiled rollout writes into work arrays where nothing is clipped."""
        fast = self._fast_rollout()
        if fast is not None:
            fast()
            X2, U2, lib = self._X2, self._U2, kernels.library()
            if (lib.all_finite(_addr(X2), X2.size) if lib is not None else np.isfinite(X2).all()) and (
                    self.efforts is None or _inside(U2, self.efforts, self._box_work)):
                np.copyto(self.X, X2)
                np.copyto(self.U, U2)
                return True
        X, U, o, O = self.problem.bounded_rollout(self.o, self.O, kernel=Sweeps.compiled)
        if not np.all(np.isfinite(X)):
            return False
        self.X[:], self.U[:] = X, U
        if o is not self.o:
            self.o[:], self.O[:] = o, O
        return True

    def _fast_rollout(self):
        """A call rolling ``o, O`` out from ``x0`` into ``_X2, _U2`` with the model's compiled rollout (the one
        ``Problem.controller_rollout`` takes; addresses taken once, again if an array was replaced), or None
        where the model has none."""
        keep = (self.problem.x0, self.o, self.O)
        if self._fast is None or (self._fast and any(a is not b for a, b in zip(keep, self._fast[0]))):
            from raico.plants.fast_analytic import FastAnalyticDynamics

            dyn, self._fast = self.problem.dynamics, False
            if isinstance(dyn, FastAnalyticDynamics) and \
                    type(dyn).controller_rollout is FastAnalyticDynamics.controller_rollout and \
                    all(a.flags.c_contiguous and a.dtype == np.float64 for a in keep):
                c = dyn._compiled()
                if c is not None and c.n == self.m and 2 * c.n == self.n:
                    self._X2, self._U2 = np.empty_like(self.X), np.empty_like(self.U)
                    args = (c.ctx_address, self.T, *(a.ctypes.data for a in (*keep, self._X2, self._U2)))
                    fn = c.lib.dyn_controller_rollout
                    self._fast = (keep, lambda: fn(*args))
        return self._fast[1] if self._fast else None

    def load(self, X: np.ndarray, U: np.ndarray, o: np.ndarray, O: np.ndarray) -> None:
        """A solution to continue from (a plan's first ``H`` steps, a cold solve)."""
        self.X[:], self.U[:], self.o[:], self.O[:] = X, U, o, O
        self.solved = True

    def refresh_times(self) -> None:
        """The window's terms changed their times (a tick of the receding horizon): the sweeps' record of
        which terms cost which step and the compiled task messages' active steps follow (in place)."""
        sw = self.sw
        sw.active = self.inner.active_state_terms()
        for t, a in enumerate(sw.active):
            sw._active_flags[t] = bool(a)
        if self._task_views is None:
            self._task_views = _compiled_active_views(sw, self.inner)
        steps = sw._steps
        for term, view in self._task_views:
            view[:] = term.active(steps)

    # -- the iterations
    def iterate(self, iterations: int = 1) -> int:
        """``iterations`` of the fixed schedule from the current trajectory; returns how many ran (fewer
        after a numerical failure, which keeps the last solution and raises :class:`NumericalError` if
        none ran)."""
        sw, n = self.sw, self.n
        for i in range(iterations):
            if self.pending and not self.settle():
                raise NumericalError("the controller's rollout left the finite states")
            X, U = self.X, self.U
            if not self._al_built:     # the hard constraints' penalty scales with the cost's curvature here
                self.al = sw.al = _finite_boxes(hard_constraints(self.inner, X, U, self.efforts))
                self._al_built = True
            alpha = self.alpha
            try:
                with np.errstate(all="ignore"):
                    self.cost = sw._cost(X, U)       # the task rows' derivatives too: linearize_all reuses them
                    sw.repeats = 0
                    sw.linearize_all(X, U, X, alpha)
                    sw.sweep()
            except (NumericalError, ArithmeticError, np.linalg.LinAlgError):
                if i == 0:
                    raise
                return i
            self.alpha *= self.opts.gamma
            np.copyto(self.o, sw.Z[:, :, n])
            np.copyto(self.O, sw.Z[:, :, :n])       # O = -Z[:, :, :n] (numpy's negative of a strided view buffers it)
            np.negative(self.O, out=self.O)
            if self.defer:      # the split: rolled out once the start it is for is in (settle)
                self.pending = self.solved = True
                continue
            if not self._rollout():
                raise NumericalError("the controller's rollout left the finite states")
            if self.al is not None:
                self.al.update(self.X, self.U)
            self.solved = True
        return iterations

    # -- the preparation / feedback split
    def settle(self) -> bool:
        """The end of an iteration run with ``defer`` (the split), once its start is in ``x0``: the controller
        rolled out from ``x0`` (as :meth:`iterate` does) and the multipliers' step there. False (the trajectory
        unchanged, no step) if that rollout is not finite; nothing to do (True) where nothing waits."""
        if not self.pending:
            return True
        self.pending = False
        if not self._rollout():
            return False
        if self.al is not None:
            self.al.update(self.X, self.U)
        return True

    def feedback(self, x: np.ndarray, out: np.ndarray) -> np.ndarray:
        """The feedback phase: ``out (m,) = o_0 + O_0 x`` from the current controller, clipped into the effort
        box (the control the consistent controller of :meth:`settle`'s rollout gives), ``x`` kept as the start
        ``x0``. Allocates nothing (``out`` float64, contiguous)."""
        o0, O0, lo, hi = self._fb
        x0 = self.problem.x0
        np.copyto(x0, x)
        np.dot(O0, x0, out=out)     # (numpy's matmul allocates its iterator; dot into out does not)
        out += o0
        if lo is not None:
            np.minimum(out, hi, out=out)
            np.maximum(out, lo, out=out)
        return out


class SplitTick:
    """The MPC tick split into a feedback phase and a preparation phase (Diehl's real-time iteration,
    acados' RTI), on the shifted workspace of an :class:`raico.planning.mpc.MPC` (``MPC(..., split=True)``).

    :meth:`feedback` (measurement in, control out): ``u = o_0 + O_0 x`` from the controller prepared for
    this window, clipped into the effort box; nothing else depends on ``x``. :meth:`prepare` (after the
    control is out, before the next measurement): the prepared controller rolled out from ``x`` and the
    multipliers' step there (what the whole tick does last), the window shifted to the next tick, its start
    reset to the prediction ``x_hat = X[1]`` (the model's next state under the control sent) and the tick's
    iterations run from the shifted controller's rollout from ``x_hat`` (linearization, sweeps, controller;
    the last iteration's rollout waits for the next measurement, :meth:`ShiftedAICO.settle`). The first tick
    has nothing prepared: its window is solved whole at ``x`` (the whole tick's numbers).

    Relation to the whole tick (docs/mpc.md): the prepared controller is the one the whole tick computes
    at the measurement ``x_hat``. On a linear-quadratic problem without active bounds the gains ``O`` do not
    depend on the start and the controller of AICO (alpha 0) does not depend on the trajectory it is
    linearized at, so the split's controls are the whole tick's; R-AICO's ``o`` reads its anchor (the
    trajectory linearized at), and its controls are the whole tick's where ``x = x_hat``.
    """

    def __init__(self, mpc):  # noqa: ANN001 (raico.planning.mpc.MPC)
        self.mpc, self.ws = mpc, mpc._ws
        self.prepared = False
        self._its, self._cost = 0, math.nan

    def feedback(self, x: np.ndarray) -> np.ndarray:
        """The control at the measured state ``x`` (the MPC's ``u`` buffer); the first tick: its window
        solved whole first."""
        mpc, ws = self.mpc, self.ws
        if not self.prepared:
            np.copyto(mpc.window.x0, x)
            mpc._set_tick(mpc.k)
            ws.defer = False
            self._its, self._cost = mpc._solve_shifted(False)
        return ws.feedback(x, mpc._u)

    def prepare(self) -> None:
        """After the control went out: the controller's first step kept (``fb_o, fb_O``), settled at the
        measured state, then the next window prepared."""
        mpc, ws = self.mpc, self.ws
        np.copyto(ws.fb_o, ws.o[0])
        np.copyto(ws.fb_O, ws.O[0])
        ws.settle()
        self._record()
        np.copyto(mpc.window.x0, ws.X[1])      # the prediction x_hat: the model's step under the control sent
        mpc.k += 1
        mpc._set_tick(mpc.k)
        ws.defer = True
        self._its, self._cost = mpc._solve_shifted(True)
        self.prepared = True

    def tick(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`feedback` then :meth:`prepare`, recorded (``MPC.tick``'s records; the window's after its
        settling at ``x``; the solve time: the whole call, the feedback's own in ``feedback_time``)."""
        t0 = time.perf_counter()
        u = self.feedback(x)
        t1 = time.perf_counter()
        self.prepare()
        log = self.mpc.log
        log.feedback_time[log.n - 1] = t1 - t0
        dt = time.perf_counter() - t0
        log.solve_time[log.n - 1] = dt
        log.over_budget[log.n - 1] = self.mpc.budget is not None and dt > self.mpc.budget
        return u, self.ws.fb_o, self.ws.fb_O

    def _record(self) -> None:
        mpc, ws = self.mpc, self.ws
        mpc._solved = True
        mpc._ticks += 1
        log = mpc.log
        if log.n >= log.solve_time.size:
            log.grow(log.solve_time.size)
        i = log.n
        log.iterations[i], log.cost[i] = self._its, self._cost
        if mpc.window.bounds is not None:
            log.violation[i] = mpc.window.bounds.violation(ws.X, ws.U)
        if log.predicted is not None:
            log.predicted[i] = ws.X
        log.n += 1


def _inside(U: np.ndarray, b, work: np.ndarray) -> bool:
    """Whether every control of ``U`` lies in the box of ``b`` (``Bounds``: ``u_lower <= u <= u_upper``)."""
    np.greater_equal(U, b.u_lower, out=work)
    if not work.all():
        return False
    np.less_equal(U, b.u_upper, out=work)
    return bool(work.all())


class ShiftSweeps(Sweeps):
    """:class:`Sweeps` whose linearization keeps its arrays across iterations and runs its loops compiled:
    the dynamics at every step and the control Hessians' checks in one call (``sweep_linearize`` of
    ``csweep.c``, where the model has a compiled linearization: its batch's numbers), the boxes' model
    (:meth:`FiniteBoxAL.model_into`), the cost's task rows into kept buffers, the kernel's state built once.
    The control marginals are computed only where the forward messages read them (``theta`` finite, or
    :meth:`beliefs`). The numbers are ``Sweeps``'s bit for bit. Without the kernel: ``Sweeps``'s code."""

    def __init__(self, problem: Problem, opts: AICOOptions):
        super().__init__(problem, opts)
        T, n, m = self.T, self.n, self.m
        self._Xlin = np.empty((T + 1, n))
        self._Hb, self._hb, self._Hinvb = np.empty((T, m, m)), np.empty((T, m)), np.empty((T, m, m))
        self._aeff, self._Xp2 = np.zeros((T, n)), np.empty((T + 1, n))
        self._2aIb = np.empty((n, n))
        self._marginals = False      # whether Hinv, Qbar, a_eff hold this linearization's
        self._kkey: tuple | None = None
        self._ctl: tuple | None = None   # the control messages' buffers (_control_messages), (): none
        self._al_lazy: tuple | None = None   # (X, U) of the linearization whose boxes' dense model is not built
        # the cost's task rows (the next linearization's derivatives): X, U, l_x, l_xx, per-step cost
        self._memo_bufs = (np.empty((T + 1, n)), np.empty((T, m)), np.empty((T + 1, n)), np.empty((T + 1, n, n)),
                           np.empty(T + 1))

    def linearize_all(self, X: np.ndarray, U: np.ndarray, Xprev: np.ndarray, alpha: float) -> None:
        lib = kernels.library() if self.compiled else None
        if lib is None:
            super().linearize_all(X, U, Xprev, alpha)
            return
        p, T, n = self.p, self.T, self.n
        np.copyto(self._Xlin, X)
        self.X, self.U, self.Xprev, self.alpha = self._Xlin, U, Xprev, alpha
        p.set_nominal(X, U)
        ct = self._compiled_tasks()
        if ct is not None:
            kernels.set_task_controls(ct, U)                   # the joint terms' nominal controls
        H, h = self._control_messages(U)
        np.copyto(self._Hb, H)
        np.copyto(self._hb, h)
        # (the marginals' arrays: the buffers until _control_marginals below replaces them, theta finite)
        self.H, self.h, self.Hinv, self.a_eff, self.Qbar = self._Hb, self._hb, self._Hinvb, self._aeff, self._Qbar
        RA, lx = self.RA, self._lx
        R = RA[:, :, :n]
        self._state_rows(X, U, ct, lx, R)
        # the boxes' model compiled, added in place (theta finite: its dense form for the relinearizations in
        # Python built when one asks for it, _relinearize_task); other constraints: the general model
        active, al = False, None
        if self.al is not None:
            done = self.al.model_into(X, U, lx, RA, self._Hb, self._hb) if isinstance(self.al, FiniteBoxAL) else None
            active = bool(done)
            if done is None:
                al = self.al.model(X, U)
        if al is not None:     # the constraints' control part: h = H u - l_u (Sweeps's operations, in place)
            self._Hb += al[3]
            self._hb += np.einsum("tij,tj->ti", al[3], U)
            self._hb -= al[2]
        flags = 0
        if self.lti:
            self._fill_lti(X, U)
        elif (getter := getattr(p.dynamics, "c_linearizer", None)) is not None and getter() is not None:
            flags = kernels.LIN_DYN
        else:
            C, m = self.C, self.m
            A, a, B = self._linearize_dynamics(X[:-1], U)
            C[:, :n, :m] = B
            C[:, :n, m:m + n] = A
            np.negative(a, out=C[:, :n, m + n])
            self._check_finite(C)
        self._run_linearize(lib, flags)           # the dynamics (flags), the checks of H and h
        self._marginals = self.relocate
        if self.relocate:     # numpy's marginals, kept in the buffers the kernel's state points to
            self._control_marginals()
            np.copyto(self._Hinvb, self.Hinv)
            np.copyto(self._aeff, self.a_eff)
            if self.Qbar is not self._Qbar:
                np.copyto(self._Qbar, self.Qbar)
            self.Hinv, self.a_eff, self.Qbar = self._Hinvb, self._aeff, self._Qbar
        self._al_model, self._al_lazy = None, None
        if al is not None:     # the constraints' state part, kept for the relinearizations within the sweeps
            lx += al[0]
            R += al[1]
            self._al_model = (al[1], np.einsum("tij,tj->ti", al[1], X) - al[0])
        elif active:           # not None: the kernel leaves the task messages to Python, which builds it
            self._al_model, self._al_lazy = (), (X, U)
        np.matmul(R, X[:, :, None], out=RA[:, :, n:])          # r = l_xx x - l_x
        RA[:, :, n] -= lx
        if alpha:
            diag = RA.reshape(T + 1, n * (n + 1))[:, ::n + 2]  # R[:, i, i] (a view)
            diag += 2.0 * alpha
            RA[:, :, n] += np.multiply(Xprev, 2.0 * alpha, out=self._Xp2)
        self._check_finite(RA)
        self._2aI = np.multiply(self.I, 2.0 * alpha, out=self._2aIb)

    def _relinearize_task(self, t: int) -> None:
        if self._al_lazy is not None:    # the boxes' model at the linearization, dense (Sweeps.linearize_all's)
            X, U = self._al_lazy
            al = self.al.model(X, U) if self.al is not None else None
            if al is None:
                raise AssertionError("the compiled boxes were active, the general model finds none")
            self._al_model, self._al_lazy = (al[1], np.einsum("tij,tj->ti", al[1], X) - al[0]), None
        super()._relinearize_task(t)

    def _control_messages(self, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``Problem.quadratize_controls(U)``: ``H (T, m, m)``, ``h (T, m)``; where every control term is a
        :class:`raico.planning.costs.ControlCost` and there is no joint term, into kept buffers with its
        operations (``H`` does not depend on ``U``: taken from the first call), else the problem's."""
        p = self.p
        if self._ctl is None:
            plain = not p.joint_terms and all(type(t) is ControlCost for t in p.control_terms)
            self._ctl = (p.quadratize_controls(U)[0].copy(), np.empty_like(U), np.empty_like(U),
                         np.empty_like(U)) if plain else ()
        if not self._ctl or U.shape != self._ctl[1].shape:
            return p.quadratize_controls(U)
        luu, lu, e, h = self._ctl
        lu.fill(0.0)
        for t in p.control_terms:     # ControlCost.derivatives: 2 w (e or e c), e = U - target
            if t.target is None:
                np.copyto(e, U)
            else:
                np.subtract(U, t.target, out=e)
            if t.c is not None:
                np.multiply(e, t.c, out=e)
            np.multiply(2.0 * t.weight, e, out=e)
            lu += e
        np.einsum("kij,kj->ki", luu, U, out=h)
        h -= lu
        return luu, h

    def _run_linearize(self, lib, flags: int) -> None:
        st = self._kernel_state(lib)
        rc = lib.sweep_linearize(ctypes.byref(st), flags)
        if rc == kernels.ERR_H:
            raise NumericalError("control Hessian H_t is not positive definite")
        self._kernel_check(st, rc)

    def _cost(self, X: np.ndarray, U: np.ndarray) -> float:
        ct = self._compiled_tasks()
        lib = kernels.library()
        if ct is None or lib is None or not (all(a.flags.c_contiguous and a.dtype == np.float64 for a in (X, U))
                                             and lib.all_finite(_addr(X), X.size)
                                             and lib.all_finite(_addr(U), U.size)):
            return super()._cost(X, U)
        kernels.set_task_controls(ct, U)     # the joint terms' costs at these controls (reset by linearize_all)
        mx, mu, lx, lxx, per_step = self._memo_bufs
        if X.shape == mx.shape:     # the checks of kernels.task_rows hold: its call without them
            kernels.task_library().taskset_rows(ct[1], self.T + 1, _addr(self._steps), _addr(X), _addr(lx), _addr(lxx),
                                                _addr(per_step))
        else:
            kernels.task_rows(ct, self.T, X, self._steps, costs=True, out=(lx, lxx, per_step))
        np.copyto(mx, X)
        np.copyto(mu, U)
        self._task_memo = (mx, mu, lx, lxx)
        with np.errstate(all="ignore"):
            c = float(per_step.sum()) + sum((float(np.sum(t.value(U))) for t in self.p.control_terms), 0.0)
        return c if math.isfinite(c) else math.inf

    def _kernel_state(self, lib) -> kernels.SweepState:
        """``Sweeps._kernel_state``, built once and reused while the arrays it points to are the same ones
        (the iteration's alpha and whether the task messages are compiled updated)."""
        key = (self.X, self.U, self.Xprev, self.H, self.h, self.Hinv, self.a_eff, self.C, self.Qbar)
        old = self._kkey
        if self._kstate is None or old is None or any(a is not b for a, b in zip(key, old)):
            st = super()._kernel_state(lib)
            self._kkey = key
            self._kfn = (st.task_fn, st.task_ctx)
            if not st.task_fn and self._ctask:
                self._kfn = (self._ctask[0], self._ctask[1])
            return st
        st = self._kstate[0]
        st.alpha = self.alpha
        st.task_fn, st.task_ctx = self._kfn if self._al_model is None else (None, None)
        st.sp_state = 0
        ctypes.memset(st.blk, 0, self.T)
        return st

    def sweep(self) -> None:
        lib = kernels.library() if self.compiled else None
        if lib is None:
            super().sweep()
            return
        self._sweep_compiled(lib)
        if not lib.all_finite(_addr(self.Z), self.Z.size):
            raise NumericalError("non-finite controller")

    def beliefs(self) -> np.ndarray:
        if self.compiled and kernels.library() is not None and not self._marginals:
            self._control_marginals()
            self._marginals = True
        return super().beliefs()


def _compiled_active_views(sw: Sweeps, problem: Problem) -> list:
    """``(term, its active steps (T+1,) uint8 as the compiled task messages read them)`` per state term of
    ``problem`` with a nonzero weight (they follow the joint terms with one in ``compile_task_set``'s
    order); empty where the task messages are not compiled."""
    from raico.planning import kernels

    ct = sw._compiled_tasks()
    if ct is None:
        return []
    ts = kernels._TaskSet.from_address(ct[1])
    vts = (kernels._VTerm * int(ts.nterms)).from_address(int(ts.terms))
    state = [t for t in problem.state_terms if t.weight != 0]
    first = int(ts.nterms) - len(state)
    T1 = problem.T + 1
    return [(term, np.ctypeslib.as_array((ctypes.c_uint8 * T1).from_address(int(vts[first + i].active))))
            for i, term in enumerate(state)]


class FiniteBoxAL(AugmentedLagrangian):
    """The augmented Lagrangian of joint ranges, velocity and effort limits (boxes) with the same numbers on
    finite iterates and fewer passes (no ``nan_to_num``: a finite iterate's rows are finite or ``-inf`` where
    a side has no bound, which ``max(0, .)`` sends to 0 as it does); other iterates or constraints: the
    general code. Where the boxes' kernel is built (``box_al.c``) and every constraint is a box (the boxes
    on the states on distinct columns, likewise on the controls), the multipliers' step and the model run
    compiled with the numpy code's operations (the same bits): :meth:`model_into` adds the model to the
    messages in place, :meth:`update` writes the multipliers into arrays kept across updates."""

    _held: list[np.ndarray] | None = None   # the rows of the iterate being updated (one pass for both uses)
    _held_c: tuple[float, list] | None = None   # compiled: (violation, [(None, lam)]) of that iterate
    _boxes: list | None = None   # compiled: per constraint (_box_plan), for the shapes _shapes; []: not

    def _compiled(self, X: np.ndarray, U: np.ndarray) -> list | None:
        """The compiled boxes for finite ``X, U`` (built once), or None."""
        if self._boxes is None:
            self._boxes = _box_plan(self.constraints, X.shape, U.shape)
            self._viol = ctypes.c_double()
            self._shapes = (X.shape, U.shape)
        lib = kernels.library()
        if not self._boxes or lib is None or (X.shape, U.shape) != self._shapes or not all(
                a.flags.c_contiguous and a.dtype == np.float64 for a in (X, U)):
            return None
        if not (lib.all_finite(_addr(X), X.size) and lib.all_finite(_addr(U), U.size)):
            return None
        return self._boxes

    def _c_lams(self, boxes: list, X: np.ndarray, U: np.ndarray, into_y: bool) -> float:
        """lam of every box at ``X, U`` into its ``lam`` buffer (``into_y``: into its ``y`` buffer, the current
        multipliers moved there first); returns the scaled violation (``into_y``) or the active rows' count."""
        lib, out = kernels.box_library(), 0.0
        xa, ua = _addr(X), _addr(U)
        viol = ctypes.byref(self._viol) if into_y else None
        for k, (ctl, nk, _, _, _, b_s, _, ybuf, _, (ia, loa, hia, ta, ya, la)) in enumerate(boxes):
            y = self.y[k]
            if into_y and y is not None and y is not ybuf:
                np.copyto(ybuf, y)
                y = ybuf
            src = None if y is None else (ya if y is ybuf else _addr(y))
            cnt = lib.box_lams(U.shape[0] if ctl else X.shape[0], nk, ia, ua if ctl else xa, U.shape[1] if ctl else
                               X.shape[1], loa, hia, b_s, src, self._mu(self.constraints[k]), ya if into_y else la,
                               ta, viol)
            out = max(out, self._viol.value) if into_y else out + cnt
        return out

    def model_into(self, X: np.ndarray, U: np.ndarray, lx: np.ndarray, RA: np.ndarray, H: np.ndarray,
                   h: np.ndarray) -> bool | None:
        """``model`` added in place, compiled: ``l_x`` to ``lx (T+1, n)``, the Hessian's diagonal to
        ``RA[:, :, :n]`` (``RA (T+1, n, n+1)``) and to ``H (T, m, m)``, the control message's ``H u - l_u`` to
        ``h (T, m)``; returns whether a row is active (False: nothing added), None: not compiled here."""
        boxes = self._compiled(X, U)
        if boxes is None or not all(a.flags.c_contiguous for a in (lx, RA, H, h)):
            return None
        if not self._c_lams(boxes, X, U, into_y=False):
            return False
        lib = kernels.box_library()
        (T1, n), (T, m) = X.shape, U.shape
        for k, (ctl, nk, *_, (ia, *_, la)) in enumerate(boxes):
            mu = self._mu(self.constraints[k])
            if ctl:
                lib.box_model(T, nk, ia, la, mu, None, 0, _addr(H), m * m, m + 1, _addr(U), m, _addr(h), m)
            else:
                lib.box_model(T1, nk, ia, la, mu, _addr(lx), n, _addr(RA), n * (n + 1), n + 2, None, 0, None, 0)
        return True

    def update(self, X: np.ndarray, U: np.ndarray) -> None:
        boxes = self._compiled(X, U)
        if boxes is not None:
            viol = self._c_lams(boxes, X, U, into_y=True)
            self._held_c = (viol, [(None, b[7]) for b in boxes])
        else:
            self._held = self._rows(X, U)
        try:
            super().update(X, U)
        finally:
            self._held, self._held_c = None, None

    def _rows(self, X: np.ndarray, U: np.ndarray) -> list[np.ndarray] | None:
        if self._held is not None:
            return self._held
        if not (np.isfinite(X).all() and np.isfinite(U).all()):
            return None
        out = []
        for c in self.constraints:
            if type(c) is ControlBox:
                k = len(c.idx)
                G = np.full((U.shape[0] + 1, 2 * k), -np.inf)
                W = U[:, c.idx]
                np.subtract(W, c.hi, out=G[:-1, :k])
                np.subtract(c.lo, W, out=G[:-1, k:])
            elif type(c) is StateBox:
                G = c.values(X, U)
            else:
                return None
            out.append(G)
        return out

    def _lams(self, X: np.ndarray, U: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        if self._held_c is not None:
            return self._held_c[1]
        rows = self._rows(X, U)
        if rows is None:
            return super()._lams(X, U)
        out = []
        for k, (c, G) in enumerate(zip(self.constraints, rows)):
            y, mu = self.y[k], self._mu(c)
            z = mu * G if y is None else y + mu * G
            out.append((G, np.maximum(z, 0.0, out=z)))
        return out

    def violation(self, X: np.ndarray, U: np.ndarray) -> float:
        if self._held_c is not None:
            return self._held_c[0]
        rows = self._rows(X, U)
        if rows is None:
            return super().violation(X, U)
        return max((float((G / c.tol).max(initial=0.0)) for c, G in zip(self.constraints, rows) if G.size),
                   default=0.0)


def _box_plan(constraints: list, xshape: tuple[int, int], ushape: tuple[int, int]) -> list:
    """Per constraint the compiled boxes' arrays ``(control?, k, idx, lo, hi, b_s, tol, y, lam, their addresses)``
    (``y``, ``lam`` zeros ``(T+1, 2k)``), or ``[]``: no kernel, a constraint that is not a box, two boxes on one
    column."""
    if kernels.box_library() is None or not constraints:
        return []
    (T1, n), m = xshape, ushape[1]
    out: list = []
    seen: dict[bool, set[int]] = {False: set(), True: set()}
    for c in constraints:
        ctl = type(c) is ControlBox
        if not ctl and type(c) is not StateBox:
            return []
        idx = np.ascontiguousarray(c.idx, dtype=np.int64)
        k, width = len(idx), (m if ctl else n)
        if len(set(idx.tolist())) != k or seen[ctl] & set(idx.tolist()) or (k and not 0 <= idx.min() <= idx.max() < width):
            return []
        seen[ctl] |= set(idx.tolist())
        lo, hi = (np.ascontiguousarray(b, dtype=float) for b in (c.lo, c.hi))
        shape = (k,) if ctl else (T1, k)
        if lo.shape != shape or hi.shape != shape or c.tol.shape != (2 * k,):
            return []
        tol = np.ascontiguousarray(c.tol, dtype=float)
        y, lam = np.zeros((T1, 2 * k)), np.zeros((T1, 2 * k))
        out.append((ctl, k, idx, lo, hi, 0 if ctl else k, tol, y, lam,
                    tuple(a.ctypes.data for a in (idx, lo, hi, tol, y, lam))))
    return out


def _finite_boxes(al: AugmentedLagrangian | None) -> AugmentedLagrangian | None:
    """``al`` as a :class:`FiniteBoxAL` (its state taken over)."""
    if al is None:
        return None
    out = FiniteBoxAL.__new__(FiniteBoxAL)
    out.__dict__.update(al.__dict__)
    return out
