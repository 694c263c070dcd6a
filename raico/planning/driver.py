"""The one iteration loop of every solver, assembled from named pieces.

A solver (AICO / R-AICO, iLQG) supplies only its **step**: one iteration from the current
``Iterate`` to a ``Step`` (the new iterate, its cost, step size, ``mu``, repeats, whether
it moved, and optionally its own ``Stop`` reason), keeping whatever else it needs
(linearizations, messages, ``mu`` schedule) in its own state. ``drive`` owns the rest:

- the history: one ``IterationRecord`` per iteration with its wall time (seconds, the
  whole step: linearization, sweeps or backward pass, rollouts);
- the callback ``callback(record, X, U)`` after every iteration that did not diverge;
- divergence (``diverged``): the step reports a ``Status.DIVERGED`` stop (a numerical
  failure), or its cost is not finite or exceeds ``divergence_factor`` times the initial
  cost (``exploded``); the diverged iterate is dropped;
- convergence on the relative cost change, one option ``tol_rel`` for every solver, tested
  on steps that moved the iterate; the comparison is a named piece the solver picks
  (``cost_change_within``: AICO, whose cost may rise; ``cost_decrease_below``: iLQG, whose
  accepted steps lower the cost up to rounding);
- the solver's own stop reasons (iLQG: gradient test, ``mu > mu_max``), taken from the step;
- the last finite iterate (``last_finite``: the iterate of the last iteration that did not
  diverge, or the start) and the lowest-cost one (``best``).

Order of the tests after a step: divergence, relative cost change, the step's own stop.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from raico.planning.problem import Callback, IterationRecord, Status

__all__ = ["ConvergenceTest", "Iterate", "LoopOptions", "Outcome", "Status", "Step", "StepFn",
           "Stop", "cost_change_within", "cost_decrease_below", "drive", "exploded",
           "relative_decrease"]


@dataclass(frozen=True)
class Iterate:
    """One iterate: trajectory ``X (T+1, n_x)``, controls ``U (T, n_u)`` and, for solvers
    that compute one per iteration (AICO), its controller ``u_t = o_t + O_t x_t`` with
    ``o (T, n_u)``, ``O (T, n_u, n_x)`` (``None`` otherwise)."""

    X: np.ndarray
    U: np.ndarray
    o: np.ndarray | None = None
    O: np.ndarray | None = None


@dataclass(frozen=True)
class Stop:
    """A reason to stop: the status it gives and one human-readable line."""

    status: Status
    message: str


@dataclass(frozen=True)
class Step:
    """What one iteration of a solver returns.

    Attributes:
        iterate: the new iterate (the current one if the step did not move).
        cost: its cost (``inf`` after a numerical failure).
        step: step-size parameter (R-AICO: alpha; iLQG: accepted line-search step or 0).
        mu: regularization after the step (iLQG; 0 for AICO).
        repeats: relinearization repeats in the sweeps (AICO; 0 for iLQG).
        moved: whether the iterate changed; the relative-cost test applies only then.
        stop: the solver's own reason to stop after this step (``Status.DIVERGED``: a
            numerical failure, the iterate is dropped), else ``None``.
    """

    iterate: Iterate
    cost: float
    step: float = 0.0
    mu: float = 0.0
    repeats: int = 0
    moved: bool = True
    stop: Stop | None = None


StepFn = Callable[[int, Iterate], Step]
"""``step(iteration, current) -> Step``: one iteration (1-based) from ``current``."""


class LoopOptions(Protocol):
    """The options ``drive`` reads (fields of ``AICOOptions`` and ``ILQGOptions``, frozen: read-only here)."""

    @property
    def iterations(self) -> int: ...          # iteration budget (>= 1)

    @property
    def tol_rel(self) -> float: ...           # converged when the relative cost change is at most this

    @property
    def divergence_factor(self) -> float: ...  # diverged when the cost exceeds this times the initial cost


@dataclass
class Outcome:
    """What ``drive`` returns.

    Attributes:
        status: why the loop stopped.
        message: one human-readable line on why.
        history: one ``IterationRecord`` per iteration (diverged ones included).
        last_finite: the iterate of the last iteration that did not diverge (the start if
            none); solvers return this one.
        best: the lowest-cost iterate of the iterations that did not diverge (``None`` if
            none did); ``best_cost`` its cost (``inf`` if none).
    """

    status: Status
    message: str
    history: list[IterationRecord]
    last_finite: Iterate
    best: Iterate | None = None
    best_cost: float = math.inf


# -- stop predicates ------------------------------------------------------------------------
ConvergenceTest = Callable[[float, float, float], bool]
"""``test(previous, cost, tol) -> bool``: converged on the relative cost change."""


def relative_decrease(previous: float, cost: float) -> float:
    """``(previous - cost) / |previous|`` (denominator floored at 1e-300; < 0: a rise)."""
    return (previous - cost) / max(abs(previous), 1e-300)


def cost_change_within(previous: float, cost: float, tol: float) -> bool:
    """``|previous - cost| <= tol |previous|``: the cost changed by at most ``tol``, relative,
    in either direction (AICO: its cost may rise; a large rise is no convergence)."""
    return abs(previous - cost) <= tol * max(abs(previous), 1e-300)


def cost_decrease_below(previous: float, cost: float, tol: float) -> bool:
    """``relative_decrease(previous, cost) < tol``: the cost fell by less than ``tol``,
    relative, or rose (iLQG: an accepted step can raise it only within rounding)."""
    return relative_decrease(previous, cost) < tol


def exploded(cost: float, reference: float, factor: float) -> bool:
    """``True`` if ``cost`` is not finite or exceeds ``factor * reference`` (a finite,
    positive ``reference``; otherwise only non-finite costs count)."""
    if not math.isfinite(cost):
        return True
    return reference > 0 and math.isfinite(reference) and cost > factor * reference


def _divergence(step: Step, it: int, reference: float, factor: float) -> Stop | None:
    """``Stop(DIVERGED)`` if the step failed numerically or its cost exploded."""
    if step.stop is not None and step.stop.status is Status.DIVERGED:
        return Stop(Status.DIVERGED, f"iteration {it}: {step.stop.message}")
    if exploded(step.cost, reference, factor):
        return Stop(Status.DIVERGED, f"iteration {it}: cost {step.cost:.3g} not finite or "
                                     f"above {factor:g} x initial cost {reference:.3g}")
    return None


def _convergence(step: Step, previous: float | None, tol: float,
                 test: ConvergenceTest) -> Stop | None:
    """``Stop(CONVERGED)`` if the step moved and ``test(previous, cost, tol)`` holds (no
    test if ``previous`` is ``None``)."""
    if not step.moved or previous is None or not test(previous, step.cost, tol):
        return None
    rel = relative_decrease(previous, step.cost)
    return Stop(Status.CONVERGED, f"relative cost change {rel:.2e} below tol_rel={tol:g}")


# -- the loop -------------------------------------------------------------------------------
def drive(step: StepFn, start: Iterate, options: LoopOptions, *, initial_cost: float,
          reference_cost: float | None = None, test: ConvergenceTest = cost_change_within,
          callback: Callback | None = None) -> Outcome:
    """Run ``step`` for at most ``options.iterations`` iterations from ``start``.

    Args:
        step: the solver's iteration (``StepFn``).
        start: the initial iterate (returned as ``last_finite`` if the first step diverges).
        options: ``iterations``, ``tol_rel``, ``divergence_factor`` (``LoopOptions``).
        initial_cost: cost of the initial guess rolled out; the divergence reference (the
            first iteration's cost instead if it is not finite and positive).
        reference_cost: the cost the first iteration's relative change is measured from
            (iLQG: the initial cost); ``None``: the test starts at the second iteration
            (AICO: its first iterate is not the rollout of the initial guess).
        test: the relative-cost-change test (``cost_change_within`` or
            ``cost_decrease_below``), called as ``test(previous, cost, options.tol_rel)``.
        callback: called with ``(record, X, U)`` after each iteration that did not diverge.

    Returns:
        ``Outcome``: status, message, history, the last finite and the best iterate.
    """
    out = Outcome(Status.MAX_ITERATIONS, f"reached {options.iterations} iterations", [], start)
    current, previous, reference = start, reference_cost, initial_cost
    t_start = time.perf_counter()
    for it in range(1, options.iterations + 1):
        t0 = time.perf_counter()
        s = step(it, current)
        now = time.perf_counter()
        rec = IterationRecord(it, s.cost, now - t0, now - t_start, s.step, s.mu, s.repeats, s.moved)
        out.history.append(rec)
        if it == 1 and not (math.isfinite(reference) and reference > 0):
            reference = s.cost
        stop = _divergence(s, it, reference, options.divergence_factor)
        if stop is None:
            current = out.last_finite = s.iterate
            if s.cost < out.best_cost:
                out.best, out.best_cost = current, s.cost
            if callback is not None:
                callback(rec, current.X, current.U)
            stop = _convergence(s, previous, options.tol_rel, test) or s.stop
            if s.moved:
                previous = s.cost
        if stop is not None:
            out.status, out.message = stop.status, stop.message
            break
    return out
