"""The evaluate stage: one run's metrics from its plan and, optionally, its rollout.

``evaluation.json``: final cost, via-point errors, the plan's task verdict (``task``: every via-point
term against its tolerance in its unit, the worst named, as the plan stage judged it), iterations,
iterations to a 0.1% relative cost change, wall time and, with a rollout, the executed via-point
errors, the execution's task verdict (``executed_task``: execute's judgement,
``raico.stages.evaluate.metrics.executed_task``) and the planned-vs-executed RMSE; ``cost.png``: cost per
iteration.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from raico.stages.base import Artifact, Stage, StageConfig, StageOutput
from raico.stages.evaluate.metrics import executed_task
from raico.stages.registry import DESCRIPTIONS

EVALUATION_FILE = "evaluation.json"
COST_PNG = "cost.png"


@dataclass(frozen=True)
class EvaluateConfig(StageConfig):
    """Inputs only: a plan and, optionally, an execution of that plan."""

    INPUTS = ("plan", "rollout")
    INPUT_STAGES = {"plan": "plan", "rollout": "execute"}
    HELP = {"plan": "Key (or prefix) of a plan artifact.", "rollout": "Key of an execute artifact of that plan."}

    plan: str | None = None
    rollout: str | None = None

    def validate(self) -> None:
        if self.plan is None:
            raise ValueError("evaluate needs --plan KEY")


def iterations_to(costs: np.ndarray, rel: float = 1e-3) -> int | None:
    """First iteration (1-based) after which the relative cost change is below ``rel``, or None."""
    if costs.size < 2:
        return None
    change = np.abs(np.diff(costs)) / np.maximum(np.abs(costs[1:]), 1e-300)
    hits = np.flatnonzero(change < rel)
    return int(hits[0] + 2) if hits.size else None


def evaluate(plan: Artifact, rollout: Artifact | None) -> dict:
    """The metrics of one run (see the module docstring)."""
    if rollout is not None and rollout.inputs != (plan.ref,):
        raise ValueError(f"rollout {rollout.key} was not executed from plan {plan.key}")
    costs = plan.arrays("plan.npz")["costs"]
    pm = plan.metrics
    metrics = {"plan": plan.key, "config": plan.config, "status": plan.status,
               "initial_cost": pm.get("initial_cost"), "final_cost": pm.get("final_cost"),
               "cost_ratio": pm.get("cost_ratio"), "iterations": pm.get("iterations"),
               "iterations_to_0.1%": iterations_to(costs), "wall_time_s": pm.get("wall_time_s"),
               "via_point_errors": pm.get("via_point_errors"), "task": pm.get("task")}
    if rollout is not None:
        rm = rollout.metrics
        metrics.update(rollout=rollout.key, execution_status=rollout.status,
                       executed_via_point_errors=rm.get("via_point_errors"),
                       executed_task=executed_task(rm.get("task"), str(rollout.status)),
                       rmse_planned_executed=rm.get("rmse_planned_executed"),
                       **{k: rm[k] for k in rm if k.startswith("cog_") or k == "torque_saturation"})
    return metrics


def cost_png(path: Path, costs: np.ndarray, initial: float | None, cfg: dict) -> None:
    """Cost per iteration (log scale), iteration 0 = the initial trajectory."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.4))
    it = np.arange(0, len(costs) + 1)
    ax.semilogy(it, np.r_[initial if initial else np.nan, costs], marker=".")
    ax.set_xlabel("iteration (0 = initial trajectory)")
    ax.set_ylabel("cost")
    ax.set_title(f"{cfg.get('plant')} {cfg.get('task')} {cfg.get('solver')} ({cfg.get('dynamics')})", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def run(cfg: EvaluateConfig, inputs: dict[str, Artifact], progress=None) -> StageOutput:
    plan = inputs["plan"]
    metrics = evaluate(plan, inputs.get("rollout"))
    costs = plan.arrays("plan.npz")["costs"]
    return StageOutput(status="ok", metrics=metrics, documents={EVALUATION_FILE: metrics},
                       figures={COST_PNG: lambda p: cost_png(p, costs, metrics["initial_cost"], plan.config)})


STAGE = Stage(name="evaluate", config_cls=EvaluateConfig, run=run, sources=("raico.planning", "raico.stages.evaluate", "raico.stages.base"),
              data_files=(EVALUATION_FILE, COST_PNG),
              description=DESCRIPTIONS["evaluate"])
