"""Why the default plan fails where it does: ``python -m bench.suite_losses RUN.json [--best FULL.json] [--docs]``.

For every suite problem whose default plan (``R-AICO robust, bounded``) in ``RUN.json`` (``bench.suite``'s
document) does not execute ``ok`` with its task achieved: the executed miss (the worst task term's error against
its tolerance), the final cost against the best feasible cost known (from ``--best``, a full suite run: the
lowest final cost of a plan inside the limits, or the direct-transcription reference's feasible cost), and the
plan itself re-planned in this process at the suite's budget and at ``LONG`` times it (plan-level task verdict
and status, no execution), from which the cause is read (:func:`cause`). Writes ``DIR/suite_losses.md`` and
``.json`` beside ``RUN.json`` and, with ``--docs``, the table into docs/suite.md between its markers. With ``--base
FULL.json`` a rerun of a few problems (``RUN.json``) replaces those runs of a full one (:func:`overlay`): the table
then covers every problem, its rerun ones marked.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from pathlib import Path

import numpy as np

LONG = 10            # the long budget: this many times the suite's iterations ...
LONG_MAX = 400       # ... at most this many
DEFAULT = "R-AICO robust, bounded"
BEGIN, END = "<!-- suite-losses:begin -->", "<!-- suite-losses:end -->"


def replan(suite, label: str, iterations: int, velocity: bool = True) -> dict:
    """The default plan of problem ``label`` at ``iterations``: status, cost, the plan's own task verdict, and the
    largest ratio of a joint's speed to its velocity limit; ``velocity = False``: without the velocity limits."""
    import dataclasses

    from raico.pipeline.experiments import suite as S
    from raico.planning.achieved import task_errors, task_verdict
    from raico.planning.problem import Problem
    from raico.planning.solvers import solve
    from raico.stages.plan.stage import PlanConfig, build_problem, quasi_static_controls

    p = next(p for p in suite.problems if p.label == label)
    s = next(s for s in suite.solvers if s.label == DEFAULT)
    cfg = PlanConfig(**{**S.options(p, s), "iterations": int(iterations)}).normalized()
    robot, _, problem, q0, _ = build_problem(cfg)
    b = problem.bounds
    if not velocity and b is not None:
        problem = Problem(problem.dynamics, problem.x0, problem.T, problem.state_terms, problem.control_terms,
                          problem.joint_terms, dataclasses.replace(b, v_index=None, v_lower=None, v_upper=None))
    init = {}
    if cfg.start == "rollout":
        init["U_init"] = np.zeros((problem.T, problem.n_u))
    elif cfg.start == "quasi-static":
        init["U_init"] = quasi_static_controls(problem, q0)
    t0 = time.process_time()
    res = solve(problem, cfg.solver, cfg.solver_options(), **init)
    v = task_verdict(task_errors(problem, res.X)) or {}
    u_excess = b.violation(res.X, res.U)[1] if b is not None and b.has_controls and np.all(np.isfinite(res.X)) else 0.0
    vlim = robot.velocity if robot.velocity is not None else np.full(robot.n_q, np.inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        speed = float(np.nanmax(np.abs(res.X[:, robot.n_q:]) / vlim, initial=0.0))
    return {"u_excess": float(u_excess), "speed_ratio": speed,"iterations": res.iterations, "status": res.status.value, "cost": float(problem.cost(res.X, res.U)),
            "achieved": bool(v.get("achieved")), "term": v.get("worst"), "error": v.get("error"), "tol": v.get("tol"),
            "unit": v.get("unit"), "message": res.message, "cpu_s": time.process_time() - t0}


def best_known(full: dict | None) -> tuple[dict, dict, dict]:
    """Per problem: the best feasible cost known (a plan inside the limits, or the feasible reference),
    whether any solver's plan executed ``ok`` with its task achieved, and the reference (feasible or not)."""
    from raico.pipeline.experiments.suite import executed_ok, inside_limits

    best: dict[str, float] = {}
    anyone: dict[str, bool] = {}
    refs = dict((full or {}).get("references") or {})
    if full is None:
        return best, anyone, refs
    for r in full["records"]:
        p = r["problem"]
        anyone[p] = anyone.get(p, False) or executed_ok(r)
        if r["final_cost"] is not None and inside_limits(r):
            best[p] = min(best.get(p, np.inf), r["final_cost"])
    for p, ref in (full.get("references") or {}).items():
        if ref.get("feasible") and ref.get("cost") is not None:
            best[p] = min(best.get(p, np.inf), ref["cost"])
    return best, anyone, refs


def _miss(note: str) -> tuple[float | None, float | None, str]:
    m = re.search(r"'([^']+)' ([0-9.e+-]+) (\S+) [<>]=? ([0-9.e+-]+)", note or "")
    return (float(m.group(2)), float(m.group(4)), m.group(3)) if m else (None, None, "")


def cause(rec: dict, at: dict, long: dict, anyone: bool | None, best: float | None = None,
          ref: dict | None = None, free: dict | None = None) -> str:
    """The cause of a default plan's failure, read from its execution and its re-plans ``at`` the suite's
    budget and at the ``long`` one (in this order: the start, the execution, the budget, the optimum);
    ``best``: the best feasible cost known, ``ref``: the direct-transcription reference (feasible or not);
    ``free``: the plan at the budget without the velocity limits (a velocity limit that binds: before the optimum)."""
    ex, effort = rec["execution"], rec.get("effort_excess") or 0.0
    if "start is outside" in (at["message"] or "") and "inside at no step" in (at["message"] or ""):
        return ("start outside a joint range: the velocity limits cannot bring it back within the horizon; "
                f"execution {ex}")
    plan_ok = at["achieved"] and at["status"] != "out-of-bounds"
    if ex not in ("ok", None):
        extra = f", its torques {effort:.3g} N m beyond an effort limit" if effort > 1e-6 else ""
        if at.get("u_excess", 0.0) > 0:   # the plan's controls were not clipped: its clipped rollout failed
            extra += (" (the effort constraint not met in the budget, and the plan's controller rolled out with its "
                      "controls clipped diverges: the plan keeps them)")
        return f"execution {ex}{extra}" + (" (the plan itself achieves the task)" if plan_ok else
                                           f"; the plan misses too ({at['status']})")
    if plan_ok:
        return "execution: the plan achieves the task, its execution misses (tracking error at the task's step)"
    if long["achieved"] and long["status"] != "out-of-bounds":
        return (f"budget: the augmented Lagrangian needs more iterations (achieved at {long['iterations']}, "
                f"cost {long['cost']:.4g}; at the budget {at['status']})")
    if free is not None and free["achieved"] and free["status"] != "out-of-bounds" and free["speed_ratio"] > 1.0:
        return (f"velocity limits bind: without them the plan achieves the task in the budget at cost "
                f"{free['cost']:.4g}, its joints up to {free['speed_ratio']:.3g}x their velocity limits")
    lower = []
    if best is not None and best < long["cost"] / 1.1:
        lower.append(f"a feasible plan costs {best:.4g}")
    if ref and ref.get("cost") is not None and not ref.get("feasible") and ref["cost"] < long["cost"] / 1.1:
        lower.append(f"SNOPT from it reaches {ref['cost']:.4g} (dynamics defect {ref.get('defect', float('nan')):.2g}, "
                     "not feasible)")
    if anyone is False and long["status"] != "out-of-bounds" and not lower:
        return ("the cost's optimum misses the tolerance: no solver's plan achieves the task, none feasible is "
                "cheaper by 1.1x")
    return (f"constrained local minimum or stall of the augmented Lagrangian: {long['status']} after "
            f"{long['iterations']} iterations at {long['cost']:.4g} (miss {long['error']:.3g} {long['unit']})"
            + (f"; {', '.join(lower)}" if lower else ""))


def analyse(run: dict, full: dict | None, suite_file: str | None, say) -> list[dict]:
    from raico.pipeline.experiments import suite as S

    suite = S.load(suite_file)
    best, anyone, refs = best_known(full)
    rows = []
    for rec in run["records"]:
        if rec["solver"] != DEFAULT or S.executed_ok(rec):
            continue
        p = rec["problem"]
        n = int(run["budgets"][p]["iterations"])
        at = replan(suite, p, n)
        long = replan(suite, p, min(LONG * n, LONG_MAX))
        free = replan(suite, p, n, velocity=False) if not long["achieved"] or long["status"] == "out-of-bounds" else None
        err, tol, unit = _miss(rec.get("task_note", ""))
        row = {"problem": p, "execution": rec["execution"], "error": err, "tol": tol, "unit": unit,
               "final_cost": rec["final_cost"], "best_feasible": best.get(p), "status": rec["status"],
               "at": at, "long": long, "free": free, "cause": cause(rec, at, long, anyone.get(p) if full else None, best.get(p), refs.get(p), free)}
        say(f"{p}: {row['cause']}")
        rows.append(row)
    return rows


KINDS = (("start outside", "start outside a range"), ("execution", "execution"), ("budget", "iteration budget"),
         ("velocity limits bind", "velocity limits bind"),
         ("the cost's optimum", "the cost's optimum misses the tolerance"),
         ("constrained local minimum", "augmented Lagrangian stalls"))


def kind_of(text: str) -> str:
    """The short name of a cause (:func:`cause`'s first words)."""
    return next((k for pre, k in KINDS if text.startswith(pre)), "other")


def _g(x, spec=".4g") -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else format(x, spec)


def markdown(run: dict, rows: list[dict], full_name: str | None) -> str:
    e = run["executions"]
    since = (f" (the rerun of {len(run['rerun'])} problems, marked *, over the full run of {run['base_date']})"
             if run.get("rerun") else "")
    head = [f"From `{run.get('date', '')}`'s run of the default plan ({DEFAULT}){since}: **{e['problems_default_ok']} of "
            f"{e['problems']}** problems executed `ok` with the task achieved; the {len(rows)} others below, each "
            f"re-planned (plan only) at the suite's budget and at {LONG}x it (at most {LONG_MAX} iterations)"
            + (f"; the best feasible cost known from {full_name}." if full_name else "."), "",
            "| problem | execution | executed miss (tol) | final cost | best feasible known | plan at the budget "
            f"| plan at {LONG}x | cause |", "|---|---|---|---|---|---|---|---|"]
    kinds: dict[str, list[str]] = {}
    for r in rows:
        kinds.setdefault(kind_of(r["cause"]), []).append(r["problem"])
    head[1:1] = ["", "By cause: " + "; ".join(f"{k} **{len(v)}** ({', '.join(v)})" for k, v in kinds.items()) + "."]
    for r in rows:
        a, lg = r["at"], r["long"]
        miss = f"{_g(r['error'], '.3g')} {r['unit']} ({_g(r['tol'], '.3g')})" if r["error"] is not None else "-"

        def plan(x):
            return (f"{x['status']}, {_g(x['cost'])}, {'achieved' if x['achieved'] else 'missed'} "
                    f"{_g(x['error'], '.3g')} {x['unit'] or ''}")
        star = "*" if r["problem"] in run.get("rerun", ()) else ""
        head.append(f"| {r['problem']}{star} | {r['execution']} | {miss} | {_g(r['final_cost'])} | {_g(r['best_feasible'])} "
                    f"| {plan(a)} | {plan(lg)} ({lg['iterations']} it.) | {r['cause']} |")
    return "\n".join(head) + "\n"


def overlay(run: dict, base: dict) -> dict:
    """``base`` (a full run's document) with the records of ``run`` (a rerun of some problems and solvers) in place
    of its records of the same problem and solver, the default plan's execution counts recounted, the rerun's
    date and the problems it covers (``rerun``) kept."""
    from raico.pipeline.experiments.suite import executed_ok

    new = {(r["problem"], r["solver"]): r for r in run["records"]}
    records = [new.pop((r["problem"], r["solver"]), r) for r in base["records"]] + list(new.values())
    mine = [r for r in records if r["solver"] == DEFAULT]
    problems = sorted({r["problem"] for r in records})
    e = dict(base.get("executions") or {})
    e.update(problems=len(problems), problems_default_ok=sum(map(executed_ok, mine)))
    return {**base, "records": records, "executions": e, "budgets": {**base["budgets"], **run["budgets"]},
            "date": run.get("date", ""), "base_date": base.get("date", ""),
            "rerun": sorted({r["problem"] for r in run["records"]})}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", help="suite.json of a run with the default plan")
    ap.add_argument("--best", default=None, help="suite.json of a full run (every solver, the reference)")
    ap.add_argument("--file", default=None, help="the suite's list file the run used")
    ap.add_argument("--base", default=None, help="suite.json of a full run the RUN (a rerun of some problems) updates")
    ap.add_argument("--docs", action="store_true", help="write the table into docs/suite.md")
    args = ap.parse_args()
    run = json.loads(Path(args.run).read_text())
    full = json.loads(Path(args.best).read_text()) if args.best else None
    if args.base:
        run = overlay(run, json.loads(Path(args.base).read_text()))
    rows = analyse(run, full, args.file, lambda s: print(s, file=sys.stderr, flush=True))
    md = markdown(run, rows, f"the full run of {full.get('date', '')} (`{Path(args.best).name}`)" if full else None)
    out = Path(args.run).parent
    (out / "suite_losses.json").write_text(json.dumps(rows, indent=1, default=str))
    (out / "suite_losses.md").write_text(md)
    print(md)
    if args.docs:
        doc = Path(__file__).resolve().parents[1] / "docs" / "suite.md"
        text = doc.read_text()
        i, j = text.index(BEGIN) + len(BEGIN), text.index(END)
        doc.write_text(text[:i] + "\n" + md + text[j:])


if __name__ == "__main__":
    main()
