"""Constraint methods measured against each other: ``python -m bench.constraint_candidates [--artifacts DIR]
[--problems LABEL ...] [--candidates NAME ...]``.

On the suite's problems (``raico/problems/suite/``, each at its own start and iteration budget, from the default
plan's options with hard bounds) every candidate (:data:`CANDIDATES`) whose ``applies(problem)`` holds plans
once, in this process, niced by the caller: final cost, inside the limits (the suite's tolerances: ranges 1e-3 rad,
velocity limits 1e-3 rad/s, efforts 1e-6 N m), the iteration from which every iterate is inside them, iterations, CPU
time and status, at the suite's budget and at 10x it (at most 400). ``unbounded`` (R-AICO robust without hard bounds) runs first on each: a problem is measured only
where a candidate applies and, with ``--binding``, where the unbounded plan leaves a box the candidates keep;
where it leaves the effort box, the problem with only that box (:func:`efforts_only`, BoxFDDP's problem) too.
Writes ``DIR/bench/constraint_candidates.json`` and ``.md`` (docs/suite.md's "Constraint methods measured"
through ``scripts/readme_numbers.py``).

A candidate is a :class:`Candidate`: a label, ``applies(problem) -> bool`` and ``run(problem, options, init,
callback) -> Result`` (``options``: the default plan's solver options, a dict; ``init``: ``X_init``/``U_init``);
another method joins with one :func:`register` call.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

MAX_ITERATIONS = 400   # the longest budget measured
DEFAULT = "R-AICO robust, bounded"   # the suite's solver entry whose options every candidate starts from


@dataclass(frozen=True)
class Candidate:
    """A constraint method: ``run(problem, options, init, callback) -> Result`` where ``applies(problem)``."""

    name: str
    label: str
    applies: Callable[[Any], bool]
    run: Callable[..., Any]


CANDIDATES: dict[str, Candidate] = {}


def register(c: Candidate) -> None:
    """Add a candidate (its ``name`` unique) to the measurement."""
    if c.name in CANDIDATES:
        raise ValueError(f"candidate {c.name!r} registered twice")
    CANDIDATES[c.name] = c


def _aico(problem, options: dict, init: dict, callback, **over):
    from raico.planning.aico import AICOOptions, aico

    keys = set(AICOOptions.field_names())
    return aico(problem, AICOOptions(**{k: v for k, v in {**options, **over}.items() if k in keys}),
                callback=callback, **init)


def _unbounded(problem):
    from raico.planning.problem import Problem

    return Problem(problem.dynamics, problem.x0, problem.T, problem.state_terms, problem.control_terms,
                   problem.joint_terms, None)


def _has_bounds(problem) -> bool:
    return problem.bounds is not None


def _control_box(problem) -> bool:
    from raico.planning.aico.boxqp import applies

    return applies(problem)


register(Candidate("unbounded", "R-AICO robust, no bounds", _has_bounds,
                   lambda pb, o, i, cb: _aico(_unbounded(pb), o, i, cb)))
register(Candidate("lagrangian", "augmented Lagrangian (default)", _has_bounds,
                   lambda pb, o, i, cb: _aico(pb, o, i, cb, control_box="lagrangian")))
register(Candidate("boxddp", "box QP in the backward pass (BoxDDP)", _control_box,
                   lambda pb, o, i, cb: _aico(pb, o, i, cb, control_box="boxddp")))


def _boxfddp_applies(problem) -> bool:
    """crocoddyl's BoxFDDP keeps only the effort box: a peer where nothing else is bounded."""
    from raico.planning.solvers import SOLVERS

    b = problem.bounds
    return ("boxfddp" in SOLVERS and _control_box(problem)
            and not (b.has_positions or b.has_velocities or b.has_torques))


def _boxfddp(problem, options: dict, init: dict, callback):
    from raico.planning.solvers import solve

    return solve(problem, "boxfddp", {"iterations": options["iterations"]}, callback=callback)


register(Candidate("boxfddp", "crocoddyl's BoxFDDP", _boxfddp_applies, _boxfddp))


def efforts_only(problem):
    """``problem`` with only its effort box (the joint ranges and velocity limits dropped): BoxFDDP's problem."""
    import dataclasses

    b = problem.bounds
    return dataclasses.replace(problem, bounds=dataclasses.replace(
        b, q_index=None, q_lower=None, q_upper=None, v_index=None, v_lower=None, v_upper=None))


def setup(suite, label: str) -> tuple[Any, Any, dict, dict, int]:
    """Problem ``label`` of the suite with the default plan's options: robot, problem (hard bounds), solver
    options, the start (``X_init``/``U_init``) and the iteration budget."""
    from raico.pipeline.experiments import suite as S
    from raico.planning.solvers import SOLVERS
    from raico.stages.plan.stage import PlanConfig, build_problem, quasi_static_controls

    p = next(p for p in suite.problems if p.label == label)
    s = next(s for s in suite.solvers if s.label == DEFAULT)
    cfg = PlanConfig(**{**S.options(p, s), "bounds": "hard"}).normalized()
    robot, _, problem, q0, _ = build_problem(cfg)
    init: dict = {}
    if cfg.start == "rollout":
        init["U_init"] = np.zeros((problem.T, problem.n_u))
    elif cfg.start == "quasi-static":
        init["U_init"] = quasi_static_controls(problem, q0)
    opts = dataclasses.asdict(SOLVERS[cfg.solver].options(cfg.solver_options()))
    return robot, problem, opts, init, int(cfg.iterations)


def violations(robot, problem, X: np.ndarray, U: np.ndarray) -> dict[str, float | None]:
    """The suite's limit measures of a plan (its torques ``U``: the candidates here plan torques) and whether
    it is inside the suite's tolerances (of the effort limits only where ``problem`` bounds nothing else)."""
    from raico.pipeline.experiments import suite as S

    v = S.limit_violations(robot, X, U, None)
    rec = {"joint_range_excess": v["joint_range"], "velocity_excess": v["velocity"], "effort_excess": v["effort"]}
    b = problem.bounds
    if b is not None and not (b.has_positions or b.has_velocities):
        return {**rec, "inside": rec["effort_excess"] is not None and rec["effort_excess"] <= S.EFFORT_TOL}
    return {**rec, "inside": S.inside_limits(rec)}


def measure(robot, problem, opts: dict, init: dict, c: Candidate) -> dict[str, Any]:
    """One candidate's plan: final cost, limits, the first iteration inside them, iterations, CPU time, status."""
    seen: list[tuple[int, bool]] = []

    def cb(rec, X, U) -> None:  # noqa: ANN001
        seen.append((rec.iteration, bool(np.all(np.isfinite(X)) and violations(robot, problem, X, U)["inside"])))
    t0 = time.process_time()
    try:
        res = c.run(problem, opts, init, cb)
    except Exception as e:   # a peer that cannot express the problem: its row says why  # noqa: BLE001
        return {"candidate": c.name, "label": c.label, "status": f"refused: {str(e).split(':')[0]}",
                "iterations": 0, "at_box": None, "final_cost": None, "first_inside": None,
                "cpu_s": time.process_time() - t0, "inside": False}
    cpu = time.process_time() - t0
    lim = violations(robot, problem, res.X, res.U) if np.all(np.isfinite(res.X)) else {"inside": False}
    first = []     # the iteration from which every later iterate is inside (none: the plan ends outside)
    for it, inside in reversed(seen):
        if not inside:
            break
        first = [it]
    if lim["inside"] and not (seen and seen[-1][1]):   # only the plan itself, its last controller's rollout clipped
        first = [res.iterations]
    b = problem.bounds
    at_box = int(np.sum((res.U <= b.u_lower) | (res.U >= b.u_upper))) if b is not None and b.has_controls else 0
    return {"candidate": c.name, "label": c.label, "status": res.status.value, "iterations": res.iterations,
            "at_box": at_box,
            "final_cost": float(problem.cost(res.X, res.U)) if np.all(np.isfinite(res.X)) else None,
            "first_inside": first[0] if first else None, "cpu_s": cpu, **lim}


def run(labels: list[str] | None, names: list[str] | None, binding: bool, scales: tuple[int, ...] = (1,),
        say=print) -> dict[str, Any]:
    """Every candidate on every chosen suite problem (default: all but the pseudo-dynamics ones), at the suite's
    iteration budget times each of ``scales`` (at most ``MAX_ITERATIONS``)."""
    from raico.pipeline.experiments import suite as S

    suite = S.load()
    chosen = labels or [p.label for p in suite.problems if "pseudo" not in p.label]
    names = names or list(CANDIDATES)
    rows, skipped = [], {}
    for label in chosen:
        robot, problem, opts, init, budget = setup(suite, label)
        todo = [CANDIDATES[n] for n in names if CANDIDATES[n].applies(problem)]
        if not any(c.name not in ("unbounded", "lagrangian") for c in todo):
            skipped[label] = "no candidate beyond the augmented Lagrangian applies"
            continue
        opts = {**opts, "iterations": budget}
        free = measure(robot, problem, opts, init, CANDIDATES["unbounded"])
        b = problem.bounds
        u_out = (b is not None and b.has_controls and free["final_cost"] is not None
                 and (free.get("effort_excess") or 0.0) > 1e-3)
        if binding and not u_out:
            skipped[label] = f"the unbounded plan stays inside the effort box (excess {free.get('effort_excess')})"
            continue
        say(f"{label}: unbounded {free['final_cost']}, effort excess {free.get('effort_excess')}")
        head = {"problem": label, "T": problem.T, "n_u": problem.n_u, "box_binds": bool(u_out)}
        rows.append({**head, "budget": budget, **free})
        variants = [(label, problem)] + ([(f"{label} (efforts only)", efforts_only(problem))] if u_out else [])
        for name, pb in variants:
            for scale in scales:
                iters = min(MAX_ITERATIONS, budget * scale)
                for c in (CANDIDATES[n] for n in names if n != "unbounded"):
                    if not c.applies(pb):
                        continue
                    r = measure(robot, pb, {**opts, "iterations": iters}, init, c)
                    say(f"  {name} {c.name} ({iters} it.): {r['status']} cost {r['final_cost']} inside {r['inside']} "
                        f"from {r['first_inside']} it {r['iterations']} {r['cpu_s']:.1f} s")
                    rows.append({**head, "problem": name, "budget": iters, **r})
    return {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "load": os.getloadavg(),
            "cpus": os.cpu_count(), "rows": rows, "skipped": skipped}


def _f(x: Any, spec: str = ".4g") -> str:
    return "-" if x is None else format(x, spec)


def markdown(doc: dict[str, Any]) -> str:
    """The table: one row per problem and candidate; the unbounded plan's cost is the lower bound."""
    la, lb = doc["load"], doc.get("load_end", doc["load"])
    lines = [f"Measured {doc['date']} on {doc['cpus']} cpus under load {la[0]:.1f} at the start, {lb[0]:.1f} at the "
             "end (CPU seconds; shared machine). Each problem at the suite's start and iteration budget.", "",
             "| problem | method | budget | status | final cost | inside the limits | inside from | controls at the box "
             "| iterations | CPU s |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        inside = "yes" if r.get("inside") else "no" + (
            f" (effort {_f(r.get('effort_excess'), '.3g')} N m, range {_f(r.get('joint_range_excess'), '.3g')} rad, "
            f"speed {_f(r.get('velocity_excess'), '.3g')} rad/s)" if r.get("effort_excess") is not None else "")
        lines.append(f"| {r['problem']} | {r['label']} | {r['budget']} | {r['status']} | {_f(r['final_cost'])} | "
                     f"{inside} | {_f(r['first_inside'], 'd')} | {r.get('at_box', '-')} | {r['iterations']} | "
                     f"{r['cpu_s']:.1f} |")
    if doc["skipped"]:
        lines += ["", "Not measured: " + "; ".join(f"{k} ({v})" for k, v in doc["skipped"].items()) + "."]
    return "\n".join(lines) + "\n"


def main() -> None:
    from bench import truncated_candidate

    truncated_candidate.register_candidates(sys.modules[__name__])   # the joint ranges' EP messages
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--artifacts", default="artifacts")
    ap.add_argument("--problems", nargs="*", default=None, help="suite labels (default: every torque problem)")
    ap.add_argument("--candidates", nargs="*", default=None, help=f"of {', '.join(CANDIDATES)} (default: all)")
    ap.add_argument("--binding", action="store_true", help="only problems whose unbounded plan leaves the box")
    ap.add_argument("--append", action="store_true", help="keep the earlier run's rows of the other problems")
    ap.add_argument("--scales", type=int, nargs="*", default=[1, 10],
                    help=f"budgets: the suite's iterations times each (at most {MAX_ITERATIONS})")
    args = ap.parse_args()
    doc = run(args.problems, args.candidates, args.binding, tuple(args.scales),
              say=lambda s: print(s, file=sys.stderr, flush=True))
    doc["load_end"] = os.getloadavg()
    out = Path(args.artifacts) / "bench"
    out.mkdir(parents=True, exist_ok=True)
    old = out / "constraint_candidates.json"
    if args.append and old.exists():   # the earlier run's other problems kept, in their order, with its loads
        prev = json.loads(old.read_text())
        done = {r["problem"].split(" (")[0] for r in doc["rows"]}
        doc["rows"] = [r for r in prev["rows"] if r["problem"].split(" (")[0] not in done] + doc["rows"]
        doc["skipped"] = {**prev["skipped"], **doc["skipped"]}
        doc["load"], doc["date"] = prev["load"], prev["date"]
    (out / "constraint_candidates.json").write_text(json.dumps(doc, indent=1))
    (out / "constraint_candidates.md").write_text(markdown(doc))
    print(f"wrote {out / 'constraint_candidates.md'}", flush=True)


if __name__ == "__main__":
    main()
