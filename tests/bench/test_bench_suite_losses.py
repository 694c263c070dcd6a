"""bench/suite_losses.py: the cause of a failing default plan, read in order (start, execution, budget, optimum,
stall), and the table's summary by cause."""

from __future__ import annotations

from bench.suite_losses import cause, kind_of, markdown


def _plan(status="max-iterations", achieved=False, cost=10.0, iterations=40, message="", error=0.02):
    return {"status": status, "achieved": achieved, "cost": cost, "iterations": iterations, "message": message,
            "error": error, "tol": 0.01, "unit": "m", "term": "reach", "u_excess": 0.0, "speed_ratio": 0.5,
            "cpu_s": 0.0}


def test_the_causes_in_their_order():
    rec = {"execution": "ok", "effort_excess": 0.0}
    start = _plan(message="the start is outside a joint range (coordinate 2 by 1.9 rad); the plan is inside at no "
                          "step of its 100; reached 40 iterations")
    assert kind_of(cause(rec, start, start, None)) == "start outside a range"
    achieved = _plan(achieved=True, error=0.003)
    assert kind_of(cause({"execution": "fell", "effort_excess": 4.2}, achieved, achieved, None)) == "execution"
    assert kind_of(cause(rec, achieved, achieved, None)) == "execution"
    late = _plan(achieved=True, iterations=400, error=0.004)
    assert kind_of(cause(rec, _plan(status="out-of-bounds"), late, None)) == "iteration budget"
    stuck = _plan(status="converged", cost=53.2)
    assert kind_of(cause(rec, stuck, stuck, False, best=53.2)) == "the cost's optimum misses the tolerance"
    text = cause(rec, stuck, stuck, False, best=20.0)
    assert kind_of(text) == "augmented Lagrangian stalls" and "a feasible plan costs 20" in text
    free = {**_plan(achieved=True, cost=4.5, error=0.002), "speed_ratio": 9.0}
    text = cause(rec, stuck, stuck, False, best=20.0, free=free)
    assert kind_of(text) == "velocity limits bind" and "9x their velocity limits" in text
    ref = {"cost": 3.7, "feasible": False, "defect": 6e-4}
    assert "SNOPT from it reaches 3.7" in cause(rec, stuck, stuck, False, best=None, ref=ref)


def test_the_table_counts_each_cause():
    run = {"date": "today", "executions": {"problems_default_ok": 1, "problems": 3}}
    stuck = _plan(status="converged")
    rows = [{"problem": p, "execution": "ok", "error": 0.02, "tol": 0.01, "unit": "m", "final_cost": 10.0,
             "best_feasible": None, "status": "converged", "at": stuck, "long": stuck,
             "cause": cause({"execution": "ok"}, stuck, stuck, False)} for p in ("a", "b")]
    md = markdown(run, rows, None)
    assert "**1 of 3**" in md and "the cost's optimum misses the tolerance **2** (a, b)" in md
    assert md.count("\n| a |") == 1 and md.count("\n| b |") == 1


def test_a_rerun_of_some_problems_overlays_the_full_run():
    """``--base``: the rerun's records replace the full run's of the same problem and solver, the default plan's
    problems executed ``ok`` with the task achieved are recounted, and the table marks the rerun problems."""
    from bench.suite_losses import DEFAULT, overlay

    def rec(p, solver=DEFAULT, ok=False):
        return {"problem": p, "solver": solver, "execution": "ok", "task_achieved": ok, "inside_limits": True}
    base = {"date": "then", "records": [rec("a"), rec("b", ok=True), rec("a", "FDDP", ok=True)],
            "executions": {"runs": 3, "problems": 2, "problems_default_ok": 1}, "budgets": {"a": 1, "b": 2}}
    run = {"date": "now", "records": [rec("a", ok=True)], "budgets": {"a": 5}}
    out = overlay(run, base)
    assert [r["task_achieved"] for r in out["records"]] == [True, True, True]
    assert out["executions"]["problems_default_ok"] == 2 and out["executions"]["problems"] == 2
    assert out["budgets"] == {"a": 5, "b": 2} and out["rerun"] == ["a"] and out["base_date"] == "then"
    stuck = _plan(status="converged")
    rows = [{"problem": p, "execution": "ok", "error": 0.02, "tol": 0.01, "unit": "m", "final_cost": 10.0,
             "best_feasible": None, "status": "converged", "at": stuck, "long": stuck,
             "cause": cause({"execution": "ok"}, stuck, stuck, False)} for p in ("a", "b")]
    md = markdown(out, rows, None)
    assert "\n| a* |" in md and "\n| b |" in md and "over the full run of then" in md
