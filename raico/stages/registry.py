"""The pipeline's stages, by name. Adding a stage: a module under ``stages/`` that defines a
``STAGE`` (see ``raico/stages/base.py``) and one line here."""

from __future__ import annotations

from importlib import import_module

from raico.stages.base import Stage

_MODULES = {
    "babble": "raico.stages.babble",
    "plan": "raico.stages.plan.stage",
    "execute": "raico.stages.execute.stage",
    "evaluate": "raico.stages.evaluate.stage",
    "fit": "raico.stages.fit.stage",
    "learn": "raico.stages.learn",  # composite: its steps are runs of babble, fit, plan and execute
}


# Each stage command's one-line help (the stage's ``description``): kept here, beside the names, so that
# ``raico --help`` lists the commands without importing any stage (and Drake with it).
DESCRIPTIONS = {
    "babble": "Motor babbling: random desired trajectories tracked by a PD controller in Drake.",
    "plan": "Plan a movement with AICO, R-AICO, iLQG or crocoddyl's FDDP; the artifact holds the feedback "
            "controller.",
    "execute": "Execute a plan in Drake's Simulator: an arm or the pendulum with the plan's feedback controller, "
               "the free-standing Nao with the joint PD and feed-forward or the whole-body stabilizer "
               "(--controller wbc), an arm in its problem's scene; status ok, limits, tracking-lost, fell, diverged "
               "or collided.",
    "evaluate": "Evaluate one run: final cost, via-point errors, iterations, wall time, planned-vs-executed RMSE.",
    "fit": "Fit a GP dynamics model (SE-ARD per joint) to babble/execute data; schedules every or batch-N with "
           "--prior.",
    "learn": "Learn a GP forward model while planning: babble, then per episode fit, plan (on the GP with its "
             "uncertainty term: AICO, or R-AICO with --alpha > 0) and execute in Drake; every run cached.",
}


def stage_names() -> list[str]:
    return list(_MODULES)


def get_stage(name: str) -> Stage:
    """The registered stage ``name`` (``ValueError`` naming the valid ones)."""
    if name not in _MODULES:
        raise ValueError(f"unknown stage '{name}': choose one of {', '.join(_MODULES)}")
    return import_module(_MODULES[name]).STAGE
