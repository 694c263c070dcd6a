"""The pipeline's stages, by name. Adding a stage: a module under ``stages/`` that defines a
``STAGE`` (see ``stages/base.py``) and one line here."""

from __future__ import annotations

from importlib import import_module

from stages.base import Stage

_MODULES = {
    "babble": "stages.babble",
    "plan": "stages.plan.stage",
    "execute": "stages.execute",
    "evaluate": "stages.evaluate.stage",
    "fit": "stages.fit.stage",
    "learn": "stages.learn",  # composite: its steps are runs of babble, fit, plan and execute
}


def stage_names() -> list[str]:
    return list(_MODULES)


def get_stage(name: str) -> Stage:
    """The registered stage ``name`` (``ValueError`` naming the valid ones)."""
    if name not in _MODULES:
        raise ValueError(f"unknown stage '{name}': choose one of {', '.join(_MODULES)}")
    return import_module(_MODULES[name]).STAGE
