"""The execute stage: a plan executed on a Drake plant in Drake's Simulator, by the robot's kind of execution.

- fixed-base robots (``execution`` ``discrete`` or ``continuous``: the arms, the pendulum, a model file's
  robot): the plan's feedback controller, receding-horizon control, scripted pushes, the open-loop
  integration check (:mod:`raico.stages.execute.fixed`);
- floating robots (``execution = "floating"``: the Nao) free on their soles with contact, tracked by the joint
  PD or the whole-body stabilizer (:mod:`raico.stages.execute.floating`, :mod:`raico.stages.execute.wbc`).

The parameters and the rollout: :mod:`raico.stages.execute.config`. What each model, option, status and array
means: docs/execution.md.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from raico.planning.objective import objective_from_description
from raico.plants.robots import robot_for
from raico.stages.base import Artifact, Stage, StageOutput
from raico.stages.evaluate.metrics import task_errors, task_verdict, via_point_errors
from raico.stages.execute.config import ExecuteConfig, ExecuteOutput
from raico.stages.execute.fixed import execute_fixed
from raico.stages.execute.floating import execute_floating
from raico.stages.plan.stage import PLAN_FILE, PROBLEM_FILE
from raico.stages.registry import DESCRIPTIONS

ROLLOUT_FILE = "rollout.npz"


def _not_executed(desc: dict, plan: dict, problem, reason: str) -> ExecuteOutput:
    """A diverged plan: nothing is simulated; the execution's status is ``diverged``."""
    T, dt = int(desc["T"]), float(desc["dt"])
    n = len(desc["q0"])
    X = np.full((T + 1, 2 * n), np.nan)
    metrics = {"status": "diverged", "failure_time": 0.0, "reason": reason,
               "via_point_errors": via_point_errors(problem, X), "task": task_verdict(task_errors(problem, X)),
               "rmse_planned_executed": float("inf"),
               "max_tracking_error": float("inf"), "max_abs_torque": 0.0, "torque_saturation": 0.0,
               "effort_clamped_fraction": 0.0,
               "position_limit_fraction": 0.0, "limits_fraction": 0.0}
    if robot_for(desc).floating:
        metrics.update(stood=False, cog_inside_fraction=0.0, cog_min_margin=float("nan"))
    return ExecuteOutput(times=np.arange(T + 1) * dt, X=X, U=np.full((T, n), np.nan), tau=np.full((T, n), np.nan),
                         X_plan=np.asarray(plan["X"]), metrics=metrics, effort_at_limit=np.zeros((T, n), bool),
                         problem=problem)


def execute(cfg: ExecuteConfig, desc: dict, plan: dict, progress: Callable[[int, int], None] | None = None,
            plan_status: str | None = None, planning=None) -> ExecuteOutput:
    """Execute a plan (its arrays, stored problem description and status) in Drake (docs/execution.md);
    ``planning``: the plan's planning problem (``--controller mpc``; a floating robot's: a function of the
    start posture giving it, ``planning_problem`` of the plan)."""
    cfg = cfg.normalized()
    cfg.validate()
    problem = objective_from_description(desc)
    floating = robot_for(desc).floating  # executed free on its soles (raico.plants.floating)
    if floating and cfg.open_loop:
        raise ValueError("--open-loop is the fixed-base robots' integration check; a floating robot stands on its "
                         "feet")
    needed = ("X", "U") if floating or cfg.open_loop else ("X", "o", "O")
    if not all(np.all(np.isfinite(plan[k])) for k in needed):
        return _not_executed(desc, plan, problem, "the plan is not finite: not executed")
    rng = np.random.default_rng(cfg.seed)
    if floating:
        out = execute_floating(cfg, desc, plan, problem, rng, progress, planning)
    else:
        out = execute_fixed(cfg, desc, plan, problem, rng, progress, planning)
    if plan_status == "diverged":  # executed (its data may still be of use), never reported as a success
        out.metrics.update(status="diverged", failure_time=0.0,
                           reason=f"the plan diverged (executed: {out.metrics['reason']})")
        if floating:
            out.metrics["stood"] = False
    return out


def planning_problem(plan: Artifact, q0: np.ndarray | None = None):
    """The plan's planning problem rebuilt from its config (the MPC's model; its start is the plan's, or the
    posture ``q0`` at rest with the terms relative to the start made relative to it): a plan of a learned
    model (``--dynamics learned --model FIT``) gives that model, the model file plus the residual GP where the
    fit is one, with the plan's uncertainty term (``raico.planning.mpc.learned_model`` finds it)."""
    import dataclasses
    import json

    from raico.stages.plan.stage import PlanConfig, build_problem

    pcfg = PlanConfig.from_dict(plan.config)
    model = None
    fits = [ref for ref in plan.inputs if ref.startswith("fit/")]
    if fits:   # its fit, beside the plan in the same store: root/fit/KEY
        key = fits[0].split("/", 1)[1]
        path = plan.path.parent.parent / "fit" / key
        model = Artifact("fit", key, path, json.loads((path / "meta.json").read_text(encoding="utf-8")))
        pcfg = dataclasses.replace(pcfg, model=model.ref)
    problem = build_problem(pcfg, model, q0=q0)[2]
    if q0 is None:
        problem.x0[:] = np.asarray(plan.document(PROBLEM_FILE)["x0"], float)
    return problem


def run(cfg: ExecuteConfig, inputs: dict[str, Artifact], progress: Callable[[int, int], None] | None = None
        ) -> StageOutput:
    """The execute stage: ``rollout.npz`` of the plan executed in Drake."""
    plan = inputs["plan"]
    planning = None
    if cfg.controller == "mpc":
        floating = robot_for(plan.document(PROBLEM_FILE)).floating
        planning = (lambda q0: planning_problem(plan, q0)) if floating else planning_problem(plan)
    out = execute(cfg, plan.document(PROBLEM_FILE), plan.arrays(PLAN_FILE), progress, plan_status=plan.status,
                  planning=planning)
    return StageOutput(status=out.metrics["status"], metrics=out.metrics, arrays={ROLLOUT_FILE: out.arrays()},
                       payload=out)


STAGE = Stage(name="execute", config_cls=ExecuteConfig, run=run,
              sources=("raico.plants", "raico.planning", "raico.stages.execute", "raico.stages.plan", "raico.stages.base",
                       "raico.stages.evaluate.metrics"),
              data_files=(ROLLOUT_FILE,),
              description=DESCRIPTIONS["execute"],
              progress_total=lambda cfg: 0)
