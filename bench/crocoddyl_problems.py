"""crocoddyl's own problems as raico problem files: every solver through the plan stage, each plan
executed in Drake, beside crocoddyl's own run of its example.

``python -m bench.crocoddyl_problems [--artifacts DIR]`` writes ``DIR/bench/crocoddyl_problems.json``
and ``crocoddyl_problems.md`` (:func:`markdown_page`); ``make bench`` runs it too (bench/run.py).

Per problem file (``raico/problems/crocoddyl/``): R-AICO (alpha 1, the fixed schedule and the adaptive
one), AICO, iLQG and crocoddyl's FDDP (solver ``fddp``: x0 held at every node) through the plan
stage (``raico.stages.plan.stage.plan``, analytic dynamics, q0-std 0, at most 200 iterations), FDDP from
crocoddyl's own cold start (the zero state at every node: ``solve()`` without a guess) on the same
exact translation, and crocoddyl's example as crocoddyl states it (its solver, its start, and for
the Kinova Pinocchio's cos/sin continuous joints, for the Talos arm no joint damping). Each plan is
executed by the execute stage (Drake, the plan's controller).

R-AICO's alpha is 1: raico plan's default for R-AICO and the smaller of the thesis's two values
(alpha in {1, 10}, gamma = 1), not chosen on these problems.

Columns: the final cost is raico's cost of the plan (none for a diverged run) (its controller rolled out on raico's model),
which for FDDP on the exact translation is crocoddyl's own; the solver's wall time is the sum of its
iterations' times (the solvers' own clocks, bookkeeping excluded; one process, one run each on a
shared 2-core machine: ratios mean more than absolute times); the hand error is the distance of the
goal frame's origin from its target at step T, planned and executed.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ITERATIONS = 200
ALPHA = 1.0
PROBLEMS = {
    "kinova": {"file": "raico/problems/crocoddyl/kinova_reach.toml", "frame": "j2s6s200_end_effector",
               "target": [0.6, 0.2, 0.5],
               "example": "crocoddyl's examples/arm_manipulation_fwddyn.py, its log: 72 (0-based: 73 iterations), "
                          "cost 8.125, hand at (0.60058, 0.19808, 0.49717)",
               "reference_cost": 8.125},
    "kinova_in_range": {"file": "raico/problems/crocoddyl/kinova_reach_in_range.toml", "frame": "j2s6s200_end_effector",
                        "target": [0.6, 0.2, 0.5],
                        "example": "the Kinova reach with the start's joint 3 one turn higher (inside its range: "
                                   "Drake's executions start where the plan does); crocoddyl's logged cost 8.125 of "
                                   "kinova_reach.toml as the reference",
                        "reference_cost": 8.125},
    "talos_arm": {"file": "raico/problems/crocoddyl/talos_arm_reach.toml", "frame": "gripper_left_motor_double_link",
                  "target": [0.0, 0.0, 0.4],
                  "example": "crocoddyl 1.0.0's examples/arm_manipulation.py (DDP), its log: 7 iterations, cost 0.1897",
                  "reference_cost": 0.189677},
    # a humanoid on one foot: the right sole welded where crocoddyl's half_sitting puts it; every solver from the
    # quasi-static start (a zero-torque rollout of the standing humanoid at dt = 0.05 blows up)
    "talos_taichi": {"file": "raico/problems/crocoddyl/talos_taichi.toml", "frame": "gripper_left_motor_double_link",
                     "target": [0.4, 0.0, 1.2], "options": {"start": "quasi-static"}, "iterations": 60,
                     "example": "crocoddyl's examples/humanoid_taichi.py logs 76 BoxFDDP iterations and cost 7.229 "
                                "for a different problem: the free-floating Talos with contact models, three phases "
                                "(the first in double support); raico's file is its phases 2-3 on the right sole "
                                "welded, which Pinocchio's tree (rooted at the base) cannot express, so no crocoddyl "
                                "run here; the execution is on the welded robot (the whole-body stabilizer is the "
                                "Nao's)",
                     "reference_cost": None},
}
SOLVERS = [  # label, plan-stage options (the problem as crocoddyl's example states it: no hard bounds, but
    # the robust schedule and BoxFDDP also with the model's joint ranges and effort limits as hard bounds)
    ("R-AICO a=1 fixed", {"solver": "raico", "alpha": ALPHA, "alpha_schedule": "fixed", "bounds": "none"}),
    ("R-AICO a=1 adaptive", {"solver": "raico", "alpha": ALPHA, "alpha_schedule": "adaptive", "bounds": "none"}),
    ("R-AICO robust", {"solver": "raico", "alpha": ALPHA, "alpha_schedule": "robust", "bounds": "none"}),
    ("AICO", {"solver": "aico", "bounds": "none"}),
    ("iLQG", {"solver": "ilqg", "bounds": "none"}),
    ("FDDP (x0 held)", {"solver": "fddp", "bounds": "none"}),
    ("R-AICO robust, hard bounds", {"solver": "raico", "alpha": ALPHA, "alpha_schedule": "robust", "bounds": "hard"}),
    ("BoxFDDP (x0 held), effort bounds", {"solver": "boxfddp", "bounds": "hard"}),
]
# in bench/run.py's results: the rows of these problems (the in-range Kinova: the executions)
BENCH_PROBLEMS = ("kinova", "kinova_in_range", "talos_arm", "talos_taichi")


def plan_config(path: str, iterations: int = ITERATIONS, **options):
    """The plan stage's validated configuration of the problem file at ``path`` (from the repository root):
    analytic dynamics, the start held (no ``q0`` noise), ``iterations`` and the solver's ``options``."""
    from raico.stages.plan.stage import PlanConfig

    cfg = PlanConfig(problem=str(ROOT / path), dynamics="analytic", q0_std=0.0, iterations=iterations,
                     **options).normalized()
    cfg.validate()
    return cfg


def _hand_error(robot, X: np.ndarray, frame: str, target) -> float:
    """Distance (m) of ``frame``'s origin from ``target`` at the last state of ``X``."""
    if not np.all(np.isfinite(X[-1])):
        return math.inf
    ctx = robot.set_state(X[-1, :robot.n_q])
    p = robot.plant.GetFrameByName(frame).CalcPoseInWorld(ctx).translation()
    return float(np.linalg.norm(p - np.asarray(target)))


def _row(label: str, out, spec: dict, crocoddyl_cost: float | None = None, note: str = "") -> dict:
    """One solver's numbers, its plan executed in Drake."""
    from raico.stages.execute.config import ExecuteConfig
    from raico.stages.execute.stage import execute

    r, problem, robot = out.result, out.problem, out.robot
    finite = bool(np.all(np.isfinite(r.X)))
    diverged = str(r.status) == "diverged"  # its X is not a plan it stands by: no final cost
    times = [h.time_s for h in r.history]
    row = {"solver": label, "status": str(r.status), "iterations": int(r.iterations),
           "final_cost": None if diverged else float(problem.cost(r.X, r.U)) if finite else math.inf,
           "solver_cost": float(r.cost) if math.isfinite(r.cost) else math.inf,
           "crocoddyl_cost": crocoddyl_cost,
           "wall_time_s": float(sum(times)), "per_iteration_s": float(statistics.median(times)) if times else None,
           "hand_error_plan_m": _hand_error(robot, r.X, spec["frame"], spec["target"]) if finite else math.inf,
           "message": r.message, "note": note}
    target = None if spec["reference_cost"] is None else 1.1 * spec["reference_cost"]
    row["time_to_1.1x_reference_s"] = None if target is None else next(
        (h.elapsed_s for h in r.history if h.cost <= target), None)
    if finite:
        ex = execute(ExecuteConfig(plan="bench").normalized(), out.description, out.arrays())
        m = ex.metrics
        row.update(execution_status=m["status"], execution_reason=m.get("reason", ""),
                   tracking_rmse_rad=m["rmse_planned_executed"], tracking_max_rad=m["max_tracking_error"],
                   hand_error_executed_m=_hand_error(robot, ex.X, spec["frame"], spec["target"]))
    else:
        row.update(execution_status="not run (the plan is not finite)", execution_reason="",
                   tracking_rmse_rad=None, tracking_max_rad=None, hand_error_executed_m=None)
    return row


def _not_expressible(label: str, why: str) -> dict:
    """A solver that cannot take the problem: a row with its reason."""
    return {"solver": label, "status": "not expressible", "iterations": 0, "final_cost": None, "solver_cost": None,
            "crocoddyl_cost": None, "wall_time_s": None, "per_iteration_s": None, "hand_error_plan_m": None,
            "message": why.splitlines()[0], "note": why.splitlines()[0], "time_to_1.1x_reference_s": None,
            "execution_status": "-", "execution_reason": "", "tracking_rmse_rad": None, "tracking_max_rad": None,
            "hand_error_executed_m": None}


def _direct(path: str, label: str, run, spec: dict, note: str) -> dict:
    """A solver called directly on the plan stage's problem (not a registered plan solver), executed
    as a plan of solver ``fddp``."""
    from raico.stages.plan.stage import PlanOutput, build_problem

    cfg = plan_config(path, solver="fddp")
    robot, task, problem, q0, desc = build_problem(cfg)
    result, croc_cost = run(problem)
    result.solver = "fddp"
    return _row(label, PlanOutput(cfg, task, robot, problem, result, q0, desc), spec, croc_cost, note)


def _fddp_cold(problem):
    from raico.planning.crocoddyl import FDDPOptions, fddp

    r = fddp(problem, FDDPOptions(iterations=ITERATIONS, start="zero", box="no"))
    return r, r.cost


def kinova_example(problem):
    """crocoddyl's own problem: Pinocchio's cos/sin joints, FDDP's cold start; raico's cost of its
    plan differs from crocoddyl's (its state differences wrap at pi). Plain FDDP as the example runs it:
    the problem file's default hard bounds would otherwise make it BoxFDDP (``box="auto"``)."""
    from raico.planning.crocoddyl import FDDPOptions, fddp

    r = fddp(problem, FDDPOptions(iterations=ITERATIONS, start="zero", continuous="cos-sin", box="no"))
    return r, r.cost


def _talos_example(problem):
    """crocoddyl 1.0.0's run: DDP from its cold start without joint damping, stopped by 1.0.0's rule
    (sum ||Q_u||^2 < 1e-9); crocoddyl 3.2.0's DDP takes the same iterates."""
    import crocoddyl

    from raico.planning.crocoddyl import build, result
    from raico.planning.problem import IterationRecord, Status

    cp = build(problem, damping=False)
    solver = crocoddyl.SolverDDP(cp.shooting)
    history: list = []

    class Stop10(crocoddyl.CallbackAbstract):
        def __init__(self):
            crocoddyl.CallbackAbstract.__init__(self)
            self.t = time.perf_counter()
            self.stop_at = None

        def __call__(self, s, *args):
            now = time.perf_counter()
            history.append(IterationRecord(len(history) + 1, float(s.cost), now - self.t,
                                           (history[-1].elapsed_s if history else 0.0) + now - self.t,
                                           float(s.stepLength), float(s.preg)))
            if self.stop_at is None and s.isFeasible and sum(float(np.dot(q, q)) for q in s.Qu) < 1e-9:
                self.stop_at = (len(history), [np.array(x) for x in s.xs], [np.array(u) for u in s.us],
                                [np.array(k) for k in s.K])
            self.t = time.perf_counter()

    cb = Stop10()
    solver.setCallbacks([cb])
    solver.solve()

    class Stopped:  # the solver's state at 1.0.0's stop
        pass

    s = Stopped()
    if cb.stop_at is None:   # 1.0.0's rule never met: crocoddyl's own last iterate, said so
        why = (f"crocoddyl 1.0.0's rule sum ||Q_u||^2 < 1e-9 never met in {len(history)} DDP iterations: "
               "crocoddyl 3's own stop (no joint damping)")
        print(f"talos_arm, crocoddyl 1.0's example: {why}", file=sys.stderr, flush=True)
        s.xs, s.us, s.K = [np.array(x) for x in solver.xs], [np.array(u) for u in solver.us], \
            [np.array(k) for k in solver.K]
        status = Status.MAX_ITERATIONS
    else:
        n, s.xs, s.us, s.K = cb.stop_at
        history = history[:n]
        why = "crocoddyl DDP stopped by crocoddyl 1.0.0's rule sum ||Q_u||^2 < 1e-9 (no joint damping)"
        status = Status.CONVERGED
    if not history:
        raise RuntimeError("crocoddyl's DDP ran no iteration on the Talos arm's example")
    croc = history[-1].cost
    res = result(problem, s, history, status, why, math.nan, s, None, cp)
    return res, croc


def run_problem(name: str) -> dict:
    from raico.planning.crocoddyl import NotExpressible
    from raico.stages.plan.stage import plan

    spec = PROBLEMS[name]
    rows = []
    for label, opts in SOLVERS:
        try:
            out = plan(plan_config(spec["file"], spec.get("iterations", ITERATIONS), **{**opts, **spec.get("options", {})}))
        except NotExpressible as e:
            rows.append(_not_expressible(label, str(e)))
            continue
        rows.append(_row(label, out, spec, float(out.result.cost) if opts["solver"] == "fddp" else None))
    if spec["reference_cost"] is None:  # no crocoddyl run of this problem
        return {"problem": name, "file": spec["file"], "example": spec["example"], "reference_cost": None,
                "iterations_budget": spec.get("iterations", ITERATIONS), "alpha": ALPHA, "rows": rows}
    rows.append(_direct(spec["file"], "FDDP (crocoddyl's cold start)", _fddp_cold, spec,
                        "the zero state at every node, as solve() without a guess; the exact translation"))
    if name == "kinova":
        rows.append(_direct(spec["file"], "crocoddyl's example (FDDP, cos/sin joints)", kinova_example, spec,
                            "crocoddyl's own problem: its continuous joints' state differences wrap at pi"))
    elif name == "talos_arm":
        rows.append(_direct(spec["file"], "crocoddyl 1.0's example (DDP, no damping)", _talos_example, spec,
                            "crocoddyl's own problem: no joint damping (raico's Drake model damps every joint)"))
    return {"problem": name, "file": spec["file"], "example": spec["example"],
            "reference_cost": spec["reference_cost"], "iterations_budget": ITERATIONS, "alpha": ALPHA, "rows": rows}


def targets(result: dict) -> dict:
    """The targets on one problem: R-AICO's per-iteration time at most FDDP's (x0 held, the plan
    stage's), and a cost within 1.1x crocoddyl's logged one in no more wall time than crocoddyl's run
    of its example (per R-AICO schedule: met or not, with the numbers)."""
    rows = {r["solver"]: r for r in result["rows"]}
    fddp = rows["FDDP (x0 held)"]
    if result["reference_cost"] is None or fddp["per_iteration_s"] is None:
        return {}
    example = result["rows"][-1] if "example" in result["rows"][-1]["solver"] else None
    out = {}
    for label in ("R-AICO a=1 fixed", "R-AICO a=1 adaptive", "R-AICO robust"):
        if label not in rows:
            continue
        r = rows[label]
        per_it = r["per_iteration_s"] / fddp["per_iteration_s"] if r["per_iteration_s"] and fddp["per_iteration_s"] \
            else None
        t = r["time_to_1.1x_reference_s"]
        out[label] = {"per_iteration_ratio_to_fddp": per_it, "per_iteration_met": per_it is not None and per_it <= 1.0,
                      "cost_ratio_to_reference": None if r["final_cost"] is None   # diverged: no final cost
                      else r["final_cost"] / result["reference_cost"],
                      "time_to_1.1x_reference_s": t,
                      "example_wall_time_s": None if example is None else example["wall_time_s"],
                      "cost_in_time_met": None if example is None else t is not None and t <= example["wall_time_s"]}
    return out


def _fmt(x, spec: str = ".4g") -> str:
    if x is None:
        return "-"
    if isinstance(x, float) and not math.isfinite(x):
        return "inf"
    return format(x, spec)


def markdown_page(doc: dict) -> str:
    """The measured numbers as a markdown page: per problem one table of the solvers, and the targets."""
    lines = ["# crocoddyl's problems in raico", "",
             f"Measured by `python -m bench.crocoddyl_problems` ({doc.get('date', '')}; machine: "
             f"{doc.get('machine', '')}). Every solver at most {ITERATIONS} iterations, analytic dynamics, the "
             f"problem file's start posture; R-AICO's alpha {ALPHA} (raico plan's default and the thesis's smaller "
             "value, not tuned here). Final cost: raico's cost of the plan (its controller rolled out on raico's "
             "model); for FDDP on the exact translation it is crocoddyl's own. Times: the solvers' own clocks, one "
             "run each on a shared 2-core machine.", ""]
    for res in doc["problems"]:
        lines += [f"## {res['problem']}: `{res['file']}`", "", f"Reference: {res['example']}.",
                  f"At most {res.get('iterations_budget', ITERATIONS)} iterations.", "",
                  "| solver | status | iterations | final cost | crocoddyl's cost | wall (s) | per iteration (ms) "
                  "| hand error at T, plan (mm) | execution | tracking RMSE (rad) | hand error at T, executed (mm) |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in res["rows"]:
            per_it = None if r["per_iteration_s"] is None else 1e3 * r["per_iteration_s"]
            he = None if r["hand_error_plan_m"] is None else 1e3 * r["hand_error_plan_m"]
            hx = None if r["hand_error_executed_m"] is None else 1e3 * r["hand_error_executed_m"]
            lines.append(f"| {r['solver']} | {r['status']} | {r['iterations']} | {_fmt(r['final_cost'])} | "
                         f"{_fmt(r['crocoddyl_cost'])} | {_fmt(r['wall_time_s'], '.3f')} | {_fmt(per_it, '.2f')} | "
                         f"{_fmt(he, '.2f')} | {r['execution_status']} | {_fmt(r['tracking_rmse_rad'], '.3g')} | "
                         f"{_fmt(hx, '.2f')} |")
        notes = [f"- {r['solver']}: {r['note'] or r['message']}" for r in res["rows"]
                 if r["note"] or r["status"] == "diverged"]
        lines += ["", *notes, ""]
        t = res.get("targets", {})
        if t:
            lines += ["| target | R-AICO fixed | R-AICO adaptive |", "|---|---|---|"]
            f, a = t["R-AICO a=1 fixed"], t["R-AICO a=1 adaptive"]

            def met(x):
                return "no reference run" if x is None else "met" if x else "missed"

            lines.append(f"| per iteration <= FDDP's (x0 held) | {_fmt(f['per_iteration_ratio_to_fddp'], '.1f')}x: "
                         f"{met(f['per_iteration_met'])} | {_fmt(a['per_iteration_ratio_to_fddp'], '.1f')}x: "
                         f"{met(a['per_iteration_met'])} |")
            lines.append(f"| cost <= 1.1 x {res['reference_cost']:.4g} within crocoddyl's example's wall time "
                         f"({_fmt(f['example_wall_time_s'], '.3f')} s) | reached at "
                         f"{_fmt(f['time_to_1.1x_reference_s'], '.2f')} s: {met(f['cost_in_time_met'])} | reached at "
                         f"{_fmt(a['time_to_1.1x_reference_s'], '.2f')} s: {met(a['cost_in_time_met'])} |")
            lines.append("")
    return "\n".join(lines) + "\n"


def run(artifacts: Path, names=tuple(PROBLEMS)) -> dict:
    import os
    import platform

    from raico.pipeline.engine.atomic import write_file_atomic

    doc = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
           "machine": f"{os.cpu_count()} cpus, load {os.getloadavg()[0]:.1f} at start, Python "
                      f"{platform.python_version()}", "problems": []}
    for name in names:
        res = run_problem(name)
        res["targets"] = targets(res)
        doc["problems"].append(res)
        print(markdown_page({**doc, "problems": [res]}).split("\n", 4)[-1], flush=True)
    out = Path(artifacts) / "bench"
    out.mkdir(parents=True, exist_ok=True)
    write_file_atomic(out / "crocoddyl_problems.json", json.dumps(doc, indent=2, default=float))
    write_file_atomic(out / "crocoddyl_problems.md", markdown_page(doc))
    print(f"wrote {out / 'crocoddyl_problems.json'} and crocoddyl_problems.md", flush=True)
    return doc


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--artifacts", default="artifacts")
    ap.add_argument("--problem", action="append", choices=list(PROBLEMS))
    args = ap.parse_args()
    run(Path(args.artifacts), tuple(args.problem or PROBLEMS))


if __name__ == "__main__":
    main()
