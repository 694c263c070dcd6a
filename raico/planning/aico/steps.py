"""The step rules of AICO / R-AICO, one iteration each (a ``driver.StepFn``): the thesis's fixed
schedule and the adaptive one (:class:`AICOStep`), and the robust one (:class:`RobustStep`)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from raico.planning.aico.bounds import AL_INNER_TOL, in_endgame
from raico.planning.aico.cross import cross_hessian, eliminate
from raico.planning.aico.options import AICOOptions
from raico.planning.aico.sweeps import NumericalError, Sweeps, bounded_rollout
from raico.planning.aico.truncated import TruncatedSites
from raico.planning.driver import Iterate, Status, Step, Stop
from raico.planning.problem import Problem


class AICOStep:
    """One AICO / R-AICO iteration (a ``driver.StepFn``): linearize at the current iterate,
    sweep, roll the new controller out on the planning dynamics.

    State: the sweeps ``sw`` and ``alpha`` (the regularization of the next iteration,
    ``alpha^[n] = alpha^[1] gamma^(n-1)``).
    """

    def __init__(self, problem: Problem, sw: Sweeps, alpha: float, gamma: float,
                 opts: AICOOptions | None = None, initial_cost: float = math.inf):
        self.problem, self.sw, self.alpha, self.gamma = problem, sw, alpha, gamma
        self.opts = opts
        self.adaptive = opts is not None and opts.schedule == "adaptive"
        self.cur_cost = initial_cost   # cost of the iterate the next step starts from (adaptive)
        self._last_merit = math.inf    # the merit of the last iterate (the constraints' multiplier updates)
        self._K: np.ndarray | None = None   # the cross term's change of control variables (robust schedule)

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
        if self._K is not None:     # the controller of v = u + K x (the cost's cross term eliminated)
            O_new = O_new - self._K
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
        (:meth:`raico.planning.constraints.AugmentedLagrangian.update`), its cost the merit under them."""
        al = self.sw.al
        if al is None or not step.moved or (step.stop is not None and step.stop.status is Status.DIVERGED) \
                or not math.isfinite(step.cost):
            return step
        prev, self._last_merit = self._last_merit, step.cost
        falls = abs(prev - step.cost) > AL_INNER_TOL * abs(step.cost)
        every = isinstance(al, TruncatedSites)    # EP's sites: every step; their temperature where it settled
        settled = not falls if every else \
            not (falls and not getattr(al, "endgame", False) and al.violation(step.iterate.X, step.iterate.U) > 1.0)
        if not settled and not every:
            return step     # the merit still falls: its minimizer is not yet found (the multipliers wait)
        X, U = step.iterate.X, step.iterate.U
        base = step.cost - al.value(X, U)
        if settled:
            al.update(X, U)
        elif isinstance(al, TruncatedSites):    # EP's sites move every step
            al.step_sites(X, U)
        self._last_merit = base + al.value(X, U)
        return dataclasses.replace(step, cost=self._last_merit)

    def _failed(self, cur: Iterate, alpha: float, why: str) -> Step:
        """A numerical failure: cost ``inf``, status diverged."""
        return Step(cur, math.inf, step=alpha, repeats=self.sw.repeats, moved=False,
                    stop=Stop(Status.DIVERGED, why))


LINE_SEARCH = (1.0, 0.5, 0.25)   # the robust schedule's feedforward steps before a rejection
NOISE_MAX = 1e6   # the robust schedule raises the process noise by 10 per failed factorization, up to this factor
ASCENTS = 5   # the robust schedule stops after this many rejections in a row of steps the model rightly sees rise


VERY_GOOD = 0.75   # a ratio of actual to predicted decrease at least this: the model is trusted (lambda_fall)
FALL_MAX = 3      # the accelerated fall divides lambda by at most lm_factor ** FALL_MAX per step


def lambda_after(lam: float, rho: float, streak: int, o: AICOOptions, fall: str | None = None) -> tuple[float, int]:
    """``lambda`` after an accepted full step whose actual decrease is ``rho`` times the predicted one, and the
    count of such steps in a row with ``rho >= VERY_GOOD`` (``streak`` before this one).

    ``lambda_fall = "nielsen"``: ``lambda * max(1 / lm_factor, 1 - (2 min(rho, 1) - 1)^3)`` (Nielsen's rule,
    crocoddyl FDDP's /10 bound). ``"accelerated"``: the same, except that the k-th step in a row with ``rho >=
    VERY_GOOD`` divides ``lambda`` by ``lm_factor ** min(k, FALL_MAX)`` (10, 100, 1000, ...): a model right
    step after step is let reach the Newton step in a few steps, as the rejections' factor grows (2, 4, 8).
    Within ``[lambda_min, lambda_max]``. ``fall``: the rule to take instead of ``o.lambda_fall``.
    """
    if (fall or o.lambda_fall) == "accelerated" and rho >= VERY_GOOD:
        streak += 1
        new = lam / o.lm_factor ** min(streak, FALL_MAX)
    else:
        streak = 0
        new = lam * max(1.0 / o.lm_factor, 1.0 - (2.0 * min(rho, 1.0) - 1.0) ** 3)
    return min(o.lambda_max, max(o.lambda_min, new)), streak


class RobustStep(AICOStep):
    """R-AICO's robust schedule (``AICOOptions.schedule = "robust"``): Levenberg-Marquardt style
    ``alpha = lambda kappa`` with acceptance by the ratio of actual to predicted decrease.

    State: ``lam`` (relative regularization of the next trial), ``cur_cost`` (cost of the current
    iterate, ``None`` while it is a start that is no trajectory) and the quadratic model of the cost
    at the current iterate (``_model``: ``l_x (T+1, n)``, ``l_xx (T+1, n, n)``, ``l_u (T, m)``,
    ``l_uu (T, m, m)``, ``l_ux (T, m, n)`` or ``None``, the sweeps' own task and control messages before regularization).
    """

    def __init__(self, problem: Problem, sw: Sweeps, opts: AICOOptions, kappa: float,
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
        self.streak = 0   # accepted full steps in a row whose ratio is at least VERY_GOOD (lambda_fall)
        self.constrained = False   # a hard constraint has been active: Nielsen's rule from then on

    def __call__(self, it: int, cur: Iterate) -> Step:
        o = self.opts
        self.alpha = self.lam * self.kappa
        al = self.sw.al
        if al is not None and not isinstance(al, TruncatedSites):    # the budget's last part, beyond a
            al.endgame = in_endgame(it, o.iterations, al, cur.X, cur.U)    # plan's status: feasibility first
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
            if step.cost > start_cost:
                self.lam = min(o.lambda_max, lam * o.lm_factor)
            elif self._fall() == "accelerated":   # judged as every later trial: the cost's model at the start
                pred = self._predicted_decrease(cur, step.iterate)
                self.lam, self.streak = lambda_after(lam, 1.0 if pred <= 0 else (start_cost - step.cost) / pred,
                                                     self.streak, o, self._fall())
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
            self.lam, self.streak = min(o.lambda_max, lam * 2.0), 0
        else:
            self.lam, self.streak = lambda_after(lam, 1.0 if pred <= 0 else actual / pred, self.streak, o,
                                                 self._fall())
        self.nu, self.ascents = 2.0, 0
        out = self._update_constraints(Step(trial, cost, step=step.step * eps, mu=lam, repeats=step.repeats))
        self.cur_cost = out.cost
        return out

    def _fall(self) -> str:
        """The fall of lambda in force: ``lambda_fall``, but Nielsen's rule once a hard constraint has been active
        (its multiplier updates change the merit between steps; the accelerated fall there was measured worse:
        docs/planning.md, "Convergence of the robust schedule")."""
        return "nielsen" if self.constrained else self.opts.lambda_fall

    def _stationary_infeasible(self, cur: Iterate, out: Step) -> Step:
        """A stationary point of the merit that breaks a hard constraint is no solution: the multipliers and
        penalty move there (the merit changes, so does its model) and the run goes on."""
        al = self.sw.al
        if al is None or out.stop is None or out.stop.status is not Status.CONVERGED:
            return out
        if al.violation(cur.X, cur.U) <= 1.0:   # feasible: stationary, unless EP's sites are to be colder
            if not isinstance(al, TruncatedSites) or al.anneal():
                return out
            al.step_sites(cur.X, cur.U)
        else:
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
        self.streak = 0
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
            L = cross_hessian(self.problem, cur.X) if self.opts.cross_terms else None
            self._model, self._model_of, self._record_model = (sw._lx.copy(), R, lu, np.array(sw.H), L), cur, False
        self._K = eliminate(self.sw, self._model[4])
        if self.sw._al_model is not None or (self.sw.al is not None and any(y is not None for y in self.sw.al.y)):
            self.constrained = True

    def _predicted_decrease(self, cur: Iterate, new: Iterate) -> float:
        """``-(g^T d + 1/2 d^T G d)`` of the cost's quadratic model at ``cur`` along ``d = new - cur`` (with
        its cross term ``du^T l_ux dx`` where the schedule keeps it)."""
        lx, R, lu, H, L = self._model
        dX, dU = new.X - cur.X, new.U - cur.U
        q = float(np.einsum("ti,ti->", lx, dX) + 0.5 * np.einsum("ti,tij,tj->", dX, R, dX)
                  + np.einsum("ti,ti->", lu, dU) + 0.5 * np.einsum("ti,tij,tj->", dU, H, dU))
        if L is not None:
            q += float(np.einsum("ti,tij,tj->", dU, L, dX[:-1]))
        return -q
