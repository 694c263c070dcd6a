"""The objective as data: named, weighted cost terms described in plain JSON.

A task (``raico/planning/tasks.py``) builds a list of term descriptions from the robot, the
initial posture and the horizon; :func:`build_terms` turns them into cost-term objects of
``raico/planning/costs.py``. The plan artifact stores the descriptions (``problem.json``), so
execute, evaluate and the report rebuild exactly the planned objective without re-running
the task builder. The dynamics are not part of the objective: they come from the registry
(``raico.plants.dynamics_registry``).

Descriptions:

- task maps: ``{"map": "frame_points", "frame", "points" (k x 3 or null), "axes", "name"}``,
  ``{"map": "roll", "frame", "name"}``, ``{"map": "cog", "axes", "name"}``,
  ``{"map": "joints", "indices" (or null), "name"}``, ``{"map": "frame_rotation", "frame",
  "rotation" (3 x 3), "name"}`` (the error ``log3(R^T R_WF)``, rad) and ``{"map": "frame_placement",
  "frame", "rotation" (3 x 3), "translation" (3), "name"}`` (the error ``log6(M^-1 M_WF)``, linear
  part first): the via-point target of these two is ``zeros(3)``, ``zeros(6)``;
- terms: ``{"term": "via", "name", "map", "target", "times", "weight", "precision"}`` with
  ``times`` a list of steps or ``{"from": a, "to": b}`` (every step a..b);
  ``{"term": "state", "name", "target" (n_x), "times", "weight", "precision"}``;
  ``{"term": "control", "name", "weight"}`` (optionally ``"target"``: ``n_u`` values, or ``"gravity"``:
  the torque that holds the robot still, ``raico.planning.costs.ControlGravity``, with ``"controls": "torque"``;
  optionally ``"precision"``: per-joint weights, ``n_u`` values); ``{"term": "control_limit", "name",
  "weight", "lower", "upper", "controls": "torque"}`` (a torque limit: dropped when the
  dynamics' controls are accelerations); ``{"term": "inequality", "name", "map", "A", "b",
  "times", "weight"}`` (one-sided bounds ``A phi <= b``, ``raico.planning.costs.TaskInequality``;
  further keys are information, e.g. a support polygon and its margin).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from raico.planning.costs import ControlGravity
from raico.planning.term_kinds import kind_named, map_keys, term_named
from raico.plants.robots import Robot, robot_for

TermDesc = dict[str, Any]


# ------------------------------------------------------------------ descriptions
def frame_points(frame: str, name: str, axes=(0, 1, 2), points=None) -> dict:
    """A frame's origin (or points fixed in it), coordinates ``axes`` (m)."""
    pts = None if points is None else np.atleast_2d(points).astype(float).tolist()
    return {"map": "frame_points", "frame": frame, "points": pts, "axes": list(axes), "name": name}


def roll(frame: str, name: str = "roll") -> dict:
    return {"map": "roll", "frame": frame, "name": name}


def cog(axes=(0, 1, 2), name: str = "cog") -> dict:
    return {"map": "cog", "axes": list(axes), "name": name}


def joints(name: str = "joints", indices=None) -> dict:
    """Joint positions (rad): all, or those at ``indices`` of the planning coordinates."""
    return {"map": "joints", "indices": None if indices is None else [int(i) for i in indices], "name": name}


def frame_rotation(frame: str, rotation, name: str) -> dict:
    """A frame's orientation error from ``rotation`` (``R_WT (3, 3)``, world): ``log3(R_WT^T R_WF)``
    (rad, 3 rows; :class:`raico.plants.taskmaps.FrameRotationError`); its via target is ``zeros(3)``."""
    R = np.asarray(rotation, float).reshape(3, 3)
    return {"map": "frame_rotation", "frame": frame, "rotation": R.tolist(), "name": name}


def frame_placement(frame: str, rotation, translation, name: str) -> dict:
    """A frame's pose error from the pose ``(rotation (3, 3), translation (3,))`` (world):
    ``log6(M^-1 M_WF)`` (6 rows: m, then rad; :class:`raico.plants.taskmaps.FramePlacementError`); its
    via target is ``zeros(6)``."""
    R = np.asarray(rotation, float).reshape(3, 3)
    p = np.asarray(translation, float).reshape(3)
    return {"map": "frame_placement", "frame": frame, "rotation": R.tolist(), "translation": p.tolist(),
            "name": name}


def _times_desc(times) -> list[int] | dict:
    """Steps as stored: a list, or ``{"from": a, "to": b}`` for a range of step 1."""
    if isinstance(times, range):
        if times.step != 1:
            raise ValueError("a via-point range must have step 1")
        return {"from": times.start, "to": times.stop - 1}
    return [int(t) for t in times]


def via(name: str, taskmap: dict, target, times, weight: float, precision=None, tol=None) -> TermDesc:
    """Via-point ``w (x* - phi(q_t))^T C (x* - phi(q_t))`` at ``times``; ``tol``: its own tolerance of
    "task achieved" (``raico.planning.achieved.task_errors``), kept only where given."""
    times = _times_desc(times)
    d = {"term": "via", "name": name, "map": taskmap, "target": np.asarray(target, float).reshape(-1).tolist(),
         "times": times, "weight": float(weight),
         "precision": None if precision is None else np.asarray(precision, float).tolist()}
    if tol is not None:
        d["tol"] = tol
    return d


def inequality(name: str, taskmap: dict, A, b, times, weight: float, **info: Any) -> TermDesc:
    """One-sided bounds ``A phi(q_t) <= b`` at ``times``, penalized by
    ``w sum_i max(0, a_i . phi - b_i)^2``; ``info``: JSON-able facts kept with the term."""
    A = np.atleast_2d(np.asarray(A, float))
    return {"term": "inequality", "name": name, "map": taskmap, "A": A.tolist(),
            "b": np.asarray(b, float).reshape(-1).tolist(), "times": _times_desc(times), "weight": float(weight),
            **info}


def collision(name: str, taskmap: dict, margin: float, hard: bool, times, weight: float) -> TermDesc:
    """Signed distances of geometry pairs (``taskmap``: ``{"map": "distances", "name", "scene", "pairs",
    "max_distance"}``) kept at least ``margin`` (m) apart at ``times``: ``w sum max(0, margin - d)^2``
    (``raico.planning.costs.Collision``); ``hard``: the problem states it as a constraint."""
    return {"term": "collision", "name": name, "map": taskmap, "margin": float(margin), "hard": bool(hard),
            "times": _times_desc(times), "weight": float(weight)}


def control(weight: float, name: str = "control") -> TermDesc:
    return {"term": "control", "name": name, "weight": float(weight)}


def state(name: str, target, times, weight: float, precision=None) -> TermDesc:
    """State target ``w (x_t - x*)^T C (x_t - x*)`` at ``times`` (positions and velocities)."""
    return {"term": "state", "name": name, "target": np.asarray(target, float).reshape(-1).tolist(),
            "times": _times_desc(times), "weight": float(weight),
            "precision": None if precision is None else np.asarray(precision, float).tolist()}


def uncertainty(sigma_star: float, weight: float, name: str = "uncertainty", units: str = "raw") -> TermDesc:
    """The GP-uncertainty term (thesis eq. 4.3) on ``(x_t, u_t)``: built with the learned model
    by the plan stage (``raico.planning.costs.Uncertainty``), not by :func:`build_terms`. ``units``:
    ``raw`` (the predictive variance in (rad/s^2)^2, as the thesis) or ``standardized`` (over the
    training outputs' variance)."""
    d = {"term": "uncertainty", "name": name, "sigma_star": float(sigma_star), "weight": float(weight),
         "controls": "torque"}
    if units != "standardized":  # descriptions of standardized terms keep their old form (and keys)
        d["units"] = units
    return d


def control_limit(lower, upper, weight: float, name: str = "control_limit") -> TermDesc:
    """Penalty on torques outside ``[lower, upper]`` (N m); only for torque-controlled models."""
    return {"term": "control_limit", "name": name, "weight": float(weight), "controls": "torque",
            "lower": np.asarray(lower, float).tolist(), "upper": np.asarray(upper, float).tolist()}


# ------------------------------------------------------------------ building
def build_taskmap(robot, d: dict):
    """The task map of description ``d`` (its ``"map"`` key's row of :data:`raico.planning.term_kinds.MAP_KINDS`)."""
    row = kind_named(d["map"])
    if row is None:
        raise ValueError(f"unknown task map kind {d['map']!r}: valid kinds are {', '.join(map_keys())}")
    return row.build(robot, d)


def build_term(robot, d: TermDesc):
    """One cost-term object from its description (its ``"term"`` key's row of
    :func:`raico.planning.term_kinds.term_kinds`)."""
    row = term_named(d["term"])
    if row is None:
        raise ValueError(f"unknown cost term kind {d['term']!r}")
    return row.build(robot, d)


@dataclass
class Objective:
    """Built cost terms of a horizon ``T``: state terms on ``x_t``, control terms on ``u_t``, joint
    terms on both (the control toward gravity)."""

    T: int
    state_terms: list
    control_terms: list
    descriptions: list[TermDesc]
    joint_terms: list = field(default_factory=list)


def toward_gravity(d: TermDesc) -> bool:
    """Whether ``d`` is a control term toward the gravity-compensating torque (a joint term)."""
    return d["term"] == "control" and d.get("target") == "gravity"


def applies(d: TermDesc, control_kind: str) -> bool:
    """Whether term ``d`` applies to a model whose controls are ``control_kind``."""
    return d.get("controls", control_kind) == control_kind


def build_terms(robot, descriptions: list[TermDesc], T: int, control_kind: str = "torque") -> Objective:
    """The objective from term descriptions (terms that do not apply to the controls dropped)."""
    state: list = []
    controls: list = []
    kept, joint = [], []
    for d in descriptions:
        if not applies(d, control_kind):
            continue
        kept.append(d)
        if d["term"] == "uncertainty":  # needs the learned model: the plan stage builds it
            continue
        if toward_gravity(d):
            joint.append(ControlGravity(robot, d["weight"], T, d.get("precision"), name=d["name"]))
            continue
        term = build_term(robot, d)
        (state if term_named(d["term"]).side == "state" else controls).append(term)
    return Objective(T, state, controls, kept, joint)


def objective_from_description(desc: dict, robot: Robot | None = None) -> Objective:
    """The planned objective rebuilt from a stored description (execute, evaluate, report)."""
    robot = robot or robot_for(desc)
    return build_terms(robot, desc["terms"], int(desc["T"]), desc["control_kind"])
