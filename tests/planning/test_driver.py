"""The solver driver (``raico.planning.driver``) on synthetic steps whose verdict is known."""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass

import numpy as np
import pytest

from raico.planning.driver import (
    Iterate,
    Status,
    Step,
    Stop,
    cost_change_within,
    cost_decrease_below,
    drive,
)
from raico.planning.problem import STATUSES, Result


@dataclass(frozen=True)
class Opts:
    iterations: int = 10
    tol_rel: float = 1e-3
    divergence_factor: float = 1e6


def _iterate(k: int) -> Iterate:
    """Iterate number ``k``: ``X`` and ``U`` filled with ``k`` (T = 2, n_x = n_u = 1)."""
    return Iterate(np.full((3, 1), float(k)), np.full((2, 1), float(k)))


class ScriptedStep:
    """Step ``it`` returns iterate ``it`` with cost ``costs[it - 1]``; ``stops[it]`` and
    ``still[it]`` (did not move) override per iteration."""

    def __init__(self, costs, stops=None, still=()):
        self.costs, self.stops, self.still = list(costs), dict(stops or {}), set(still)
        self.calls: list[int] = []

    def __call__(self, it: int, cur: Iterate) -> Step:
        self.calls.append(it)
        moved = it not in self.still
        return Step(_iterate(it) if moved else cur, self.costs[it - 1], step=0.5 * it,
                    mu=float(it), repeats=it, moved=moved, stop=self.stops.get(it))


def _run(step, opts=Opts(), **kw):
    seen = []
    out = drive(step, _iterate(0), opts, initial_cost=kw.pop("initial_cost", 100.0),
                callback=lambda rec, X, U: seen.append((rec.iteration, X[0, 0])), **kw)
    return out, seen


def test_converges_at_the_expected_iteration():
    # relative changes: 0.5, 0.5, 5e-4 (<= 1e-3) -> converged at iteration 4
    t0 = time.perf_counter()
    out, seen = _run(ScriptedStep([8.0, 4.0, 2.0, 1.999, 1.0, 1.0]))
    wall = time.perf_counter() - t0
    assert out.status is Status.CONVERGED and out.status == "converged"
    assert len(out.history) == 4
    assert out.message == "relative cost change 5.00e-04 below tol_rel=0.001"
    assert [h.iteration for h in out.history] == [1, 2, 3, 4]
    assert [h.cost for h in out.history] == [8.0, 4.0, 2.0, 1.999]
    assert [(h.step, h.mu, h.repeats) for h in out.history][-1] == (2.0, 4.0, 4)
    # time per iteration, and since the start: elapsed covers the steps so far, within the call
    elapsed = [h.elapsed_s for h in out.history]
    assert all(h.time_s >= 0 for h in out.history) and elapsed == sorted(elapsed)
    assert all(h.elapsed_s >= sum(g.time_s for g in out.history[:k + 1]) for k, h in enumerate(out.history))
    assert elapsed[-1] <= wall
    assert seen == [(1, 1.0), (2, 2.0), (3, 3.0), (4, 4.0)]          # callback every time
    assert out.last_finite.X[0, 0] == 4.0


def test_first_iteration_compared_only_with_a_reference_cost():
    costs = [100.0, 50.0]
    out, _ = _run(ScriptedStep(costs), Opts(iterations=2))
    assert out.status is Status.MAX_ITERATIONS                       # 100 vs nothing
    out, _ = _run(ScriptedStep(costs), Opts(iterations=2), reference_cost=100.0)
    assert out.status is Status.CONVERGED and len(out.history) == 1  # 100 vs 100


def test_nan_cost_diverges_and_keeps_the_last_finite_iterate():
    out, seen = _run(ScriptedStep([8.0, 4.0, math.nan, 1.0]))
    assert out.status is Status.DIVERGED and out.status == "diverged"
    assert len(out.history) == 3 and math.isnan(out.history[-1].cost)
    assert out.message == "iteration 3: cost nan not finite or above 1e+06 x initial cost 100"
    assert out.last_finite.X[0, 0] == 2.0                            # iteration 2's iterate
    assert [i for i, _ in seen] == [1, 2]                            # no callback on divergence


def test_exploding_cost_diverges():
    out, _ = _run(ScriptedStep([50.0, 2e8, 1.0]), initial_cost=100.0)  # > 1e6 x 100
    assert out.status is Status.DIVERGED and len(out.history) == 2
    assert out.message == "iteration 2: cost 2e+08 not finite or above 1e+06 x initial cost 100"
    assert out.last_finite.X[0, 0] == 1.0


def test_without_a_positive_initial_cost_the_first_cost_is_the_reference():
    out, _ = _run(ScriptedStep([10.0, 1e8]), initial_cost=math.inf)
    assert out.status is Status.DIVERGED and len(out.history) == 2    # 1e8 > 1e6 x 10
    assert out.message == "iteration 2: cost 1e+08 not finite or above 1e+06 x initial cost 10"


def test_numerical_failure_reported_by_the_step_diverges_at_once():
    fail = Stop(Status.DIVERGED, "NumericalError: boom")
    out, seen = _run(ScriptedStep([8.0, math.inf], stops={1: fail}))
    assert out.status is Status.DIVERGED and len(out.history) == 1
    assert out.message == "iteration 1: NumericalError: boom"
    assert out.last_finite.X[0, 0] == 0.0 and seen == []            # the start
    assert out.best is None and out.best_cost == math.inf


def test_reaches_the_iteration_budget():
    costs = [100.0 / 2 ** k for k in range(10)]                     # halves: never converges
    step = ScriptedStep(costs)
    out, seen = _run(step, Opts(iterations=7))
    assert out.status is Status.MAX_ITERATIONS and out.message == "reached 7 iterations"
    assert len(out.history) == 7 and step.calls == list(range(1, 8)) and len(seen) == 7
    assert out.last_finite.X[0, 0] == 7.0


def test_solver_specific_stop_reason():
    stuck = Stop(Status.MAX_ITERATIONS, "mu > mu_max=1e+10: no descent step")
    out, seen = _run(ScriptedStep([8.0, 8.0, 1.0], stops={2: stuck}, still={2}))
    assert out.status is Status.MAX_ITERATIONS and out.message == stuck.message
    assert len(out.history) == 2 and [i for i, _ in seen] == [1, 2]  # callback still runs
    assert out.last_finite.X[0, 0] == 1.0                             # did not move
    grad = Stop(Status.CONVERGED, "gradient 1e-06 below tol_grad")
    out, _ = _run(ScriptedStep([8.0, 4.0, 1.0], stops={2: grad}))
    assert out.status is Status.CONVERGED and out.message == grad.message


def test_a_step_that_did_not_move_is_not_convergence():
    # iteration 2 leaves the iterate (and the cost) unchanged: no relative-change test
    out, _ = _run(ScriptedStep([8.0, 8.0, 4.0], still={2}), Opts(iterations=3),
                  reference_cost=100.0)
    assert out.status is Status.MAX_ITERATIONS and len(out.history) == 3


def test_best_is_the_lowest_cost_iterate_last_finite_the_last():
    out, _ = _run(ScriptedStep([5.0, 3.0, 4.0]), Opts(iterations=3))
    assert out.best.X[0, 0] == 2.0 and out.best_cost == 3.0
    assert out.last_finite.X[0, 0] == 3.0


def test_convergence_tests():
    # AICO's: change in either direction; iLQG's: a decrease below tol, or any rise
    assert cost_change_within(1.0, 1.0, 0.0) and not cost_decrease_below(1.0, 1.0, 0.0)
    assert cost_change_within(1.0, 1.0 + 1e-10, 1e-9) and cost_decrease_below(1.0, 2.0, 0.0)
    assert not cost_change_within(1.0, 2.0, 1e-9)
    assert cost_decrease_below(1.0, 1.0 - 1e-10, 1e-9)
    assert not cost_decrease_below(1.0, 0.5, 1e-9) and not cost_change_within(1.0, 0.5, 1e-9)
    out, _ = _run(ScriptedStep([8.0, 9.0]), Opts(iterations=2), test=cost_decrease_below)
    assert out.status is Status.CONVERGED                           # the rise at iteration 2
    out, _ = _run(ScriptedStep([8.0, 9.0]), Opts(iterations=2))
    assert out.status is Status.MAX_ITERATIONS


def test_status_serializes_as_its_value():
    s = Status.MAX_ITERATIONS
    assert str(s) == "max-iterations" and f"{s}" == "max-iterations" and f"{s:>15}" == \
        " max-iterations"
    assert format(s) == "max-iterations" and "-".join([s]) == "max-iterations"
    assert repr(s) == "<Status.MAX_ITERATIONS: 'max-iterations'>" and isinstance(s, str)
    assert json.dumps({"status": Status.CONVERGED}) == '{"status": "converged"}'
    assert s == "max-iterations" and Status("diverged") is Status.DIVERGED
    assert STATUSES == ("converged", "max-iterations", "diverged", "out-of-bounds")
    assert {Status.CONVERGED: 1}["converged"] == 1                    # same hash as the str
    X, U = np.zeros((3, 1)), np.zeros((2, 1))
    r = Result(X, U, U, np.zeros((2, 1, 1)), "converged", [], 0, "")
    assert r.status is Status.CONVERGED
    with pytest.raises(ValueError, match="status"):
        Result(X, U, U, np.zeros((2, 1, 1)), "done", [], 0, "")
