"""The cost terms of a problem file (``[costs.NAME]``): each ``type``'s parser and its describer.

One pair of functions per row of the cost-kind table (:data:`raico.planning.term_kinds.COST_KINDS`, which names
them): ``check_*(name, t, T)`` checks a term as written and gives its canonical form (the problem file's
``doc``, part of the cache key); ``describe_*(name, t, ctx, steps, factor)`` gives its description
(:mod:`raico.planning.objective`) on the robot at the start posture ``ctx.q0``, at ``steps`` (None: a term on the
controls, every step), its weight times ``factor`` (the convention's, ``raico.planning.problem_file``). The keys
and their meaning: docs/problem-files.md. Faults are ``ValueError`` with one line naming the term.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from raico.planning import objective as ob

TIMES = ("last", "all", "running", "every")
ANGLES = ("roll",)
CULL = 0.05   # m: a collision term's default max_distance beyond its margin (pairs farther are not queried)


@dataclass(frozen=True)
class TermContext:
    """What a term is described on: the problem (``raico.planning.problem_file.ProblemFile``), the robot and
    its start posture ``q0``."""

    problem: Any
    robot: Any
    q0: np.ndarray


# ------------------------------------------------------------------ values
def refuse_unknown(keys, valid, where: str) -> None:
    unknown = sorted(set(keys) - set(valid))
    if unknown:
        raise ValueError(f"{where}: unknown key '{unknown[0]}': valid keys are {', '.join(sorted(valid))}")


def number(v, what: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"{what} must be a finite number, got {v!r}")
    return float(v)


def nonneg(v, what: str) -> float:
    x = number(v, what)
    if x < 0:
        raise ValueError(f"{what} must be >= 0, got {v!r}")
    return x


def vector(v, what: str, n: int | None = None) -> list:
    a = np.asarray(v, dtype=float) if isinstance(v, list) else None
    if a is None or a.ndim != 1 or not np.all(np.isfinite(a)):
        raise ValueError(f"{what} must be a list of numbers, got {v!r}")
    if n is not None and a.size != n:
        raise ValueError(f"{what} has {a.size} values, expected {n}")
    return a.tolist()


def check_times(v, T: int, name: str):
    if v is None:
        raise ValueError(f"[costs.{name}] needs times: a list of steps in [0, {T}], or one of {', '.join(TIMES)}")
    if isinstance(v, dict):
        refuse_unknown(v, {"from", "to"}, f"[costs.{name}] times")
        a, b = v.get("from"), v.get("to")
        if not (isinstance(a, int) and isinstance(b, int) and 0 <= a <= b):
            raise ValueError(f"[costs.{name}] times = {{from = a, to = b}} needs integers 0 <= a <= b")
        if b > T:
            raise ValueError(f"[costs.{name}] step {b} is past the horizon: steps are in [0, T = {T}]")
        return {"from": a, "to": b}
    if isinstance(v, str):
        if v not in TIMES:
            raise ValueError(f"[costs.{name}] unknown times '{v}': choose one of {', '.join(TIMES)} or a list of steps")
        return v
    if not isinstance(v, list) or not v or not all(isinstance(t, int) and not isinstance(t, bool) for t in v):
        raise ValueError(f"[costs.{name}] times must be a non-empty list of integer steps or one of {', '.join(TIMES)}")
    bad = [t for t in v if not 0 <= t <= T]
    if bad:
        raise ValueError(f"[costs.{name}] step {bad[0]} is past the horizon: steps are in [0, T = {T}]")
    return sorted(set(v))


# ------------------------------------------------------------------ checks (the problem file as written)
def _common(name: str, t: dict, T: int, weight=None) -> dict:
    """The checks every term but a collision takes: a weight (>= 0; ``weight``: already checked), its
    steps (where it takes ``times``), names as strings, ``relative`` and ``angle``."""
    if "weight" not in t:
        raise ValueError(f"[costs.{name}] needs a weight")
    out = dict(t)
    out["weight"] = nonneg(t["weight"], f"[costs.{name}] weight") if weight is None else weight
    if "times" in _keys(t):
        out["times"] = check_times(t.get("times"), T, name)
    for key in ("frame", "in_frame", "angle", "relative", "map"):
        if key in t and not isinstance(t[key], str):
            raise ValueError(f"[costs.{name}] {key} must be a string")
    if "relative" in t and t["relative"] != "start":
        raise ValueError(f"[costs.{name}] relative must be \"start\"")
    if "angle" in t and t["angle"] not in ANGLES:
        raise ValueError(f"[costs.{name}] unknown angle '{t['angle']}': choose one of {', '.join(ANGLES)}")
    return out


def _keys(t: dict) -> frozenset[str]:
    from raico.planning.term_kinds import cost_kind

    return cost_kind(t["type"]).keys


def _with_frame(name: str, t: dict, out: dict) -> dict:
    if "frame" not in t:
        raise ValueError(f"[costs.{name}] needs a frame")
    return out


def check_task(name: str, t: dict, T: int) -> dict:
    """A term on the state or a task map without further requirements (``com``, ``posture``, ``state``,
    ``joint_limit``, ``control_limit``)."""
    return _common(name, t, T)


def check_frame_position(name: str, t: dict, T: int) -> dict:
    out = _with_frame(name, t, _common(name, t, T))
    if "moving" in t:
        out["moving"] = check_moving(name, t)
    return out


MOVING_KEYS = frozenset({"radius", "period", "axes", "phase", "velocity"})


def check_moving(name: str, t: dict) -> dict:
    """A moving target (``moving = {radius, period, axes, phase, velocity}``): a circle of ``radius`` (m) in
    the world axes ``axes`` (two of 0, 1, 2; default ``[1, 2]``) about ``target`` with ``period`` (s), starting
    at angle ``phase`` (rad), and/or a constant ``velocity`` (m/s, 3 values); a frame's origin only."""
    m = t["moving"]
    where = f"[costs.{name}] moving"
    if not isinstance(m, dict) or not m:
        raise ValueError(f"{where} must be a table of {', '.join(sorted(MOVING_KEYS))}")
    refuse_unknown(m, MOVING_KEYS, where)
    if "axes" in t or "points" in t or t.get("target") == "start":
        raise ValueError(f"[costs.{name}] a moving target is a frame's origin in 3-D (no axes or points) about "
                         "a target in m (relative = \"start\" for one relative to the start)")
    out: dict = {}
    if "radius" in m or "period" in m:
        out["radius"] = nonneg(m.get("radius", 0.0), f"{where} radius")
        period = number(m.get("period", math.nan), f"{where} period")
        if not period > 0:
            raise ValueError(f"{where} period must be a positive number of seconds")
        out["period"] = period
        axes = m.get("axes", [1, 2])
        if not (isinstance(axes, list) and len(axes) == 2 and set(axes) <= {0, 1, 2} and axes[0] != axes[1]):
            raise ValueError(f"{where} axes must be two different world axes of 0, 1, 2, got {axes!r}")
        out["axes"] = list(axes)
        out["phase"] = number(m.get("phase", 0.0), f"{where} phase")
    if "velocity" in m:
        out["velocity"] = vector(m["velocity"], f"{where} velocity", 3)
    if not out:
        raise ValueError(f"{where} needs a radius and a period, or a velocity")
    return out


def moving_offset(m: dict, time: float) -> np.ndarray:
    """The moving target's offset from ``target`` at ``time`` (s): ``r (cos(wt + phase) - cos(phase))`` on the
    first axis, ``r (sin(wt + phase) - sin(phase))`` on the second (``w = 2 pi / period``; the circle starts at
    ``target``), plus ``velocity * time``."""
    off = np.zeros(3)
    if "radius" in m:
        a, b = m["axes"]
        w, ph, r = 2.0 * math.pi / m["period"], m["phase"], m["radius"]
        off[a] += r * (math.cos(w * time + ph) - math.cos(ph))
        off[b] += r * (math.sin(w * time + ph) - math.sin(ph))
    if "velocity" in m:
        off += np.asarray(m["velocity"], float) * time
    return off


def check_frame_orientation(name: str, t: dict, T: int) -> dict:
    out = _with_frame(name, t, _common(name, t, T))
    if "angle" not in t and ("rotation" in t) == ("rpy" in t):
        raise ValueError(f"[costs.{name}] needs rotation (3 x 3) or rpy (3), or angle = \"roll\" with a target")
    return out


def check_frame_placement(name: str, t: dict, T: int) -> dict:
    out = _with_frame(name, t, _common(name, t, T))
    if "position" not in t:
        raise ValueError(f"[costs.{name}] needs a position (3)")
    return out


def check_control(name: str, t: dict, T: int) -> dict:
    """A control term: ``weight`` a number or one per joint, ``target`` numbers or ``"gravity"``."""
    if "weight" not in t:
        raise ValueError(f"[costs.{name}] needs a weight")
    if isinstance(t["weight"], list):  # per-joint weights
        weight: Any = [nonneg(w, f"[costs.{name}] weight") for w in t["weight"]]
        if not weight:
            raise ValueError(f"[costs.{name}] weight must be a number or one number per joint")
    else:
        weight = nonneg(t["weight"], f"[costs.{name}] weight")
    if isinstance(t.get("target"), str) and t["target"] != "gravity":
        raise ValueError(f"[costs.{name}] target must be {{n}} numbers or \"gravity\" (the torque that holds the "
                         f"robot still), got {t['target']!r}")
    return _common(name, t, T, weight)


def _name_pairs(v, what: str) -> list[list[str]]:
    if not isinstance(v, list) or not all(isinstance(p, list) and len(p) == 2 and all(isinstance(x, str) for x in p)
                                          for p in v):
        raise ValueError(f"{what} must be a list of [name, name] pairs")
    return [list(p) for p in v]


def check_collision(name: str, t: dict, T: int) -> dict:
    """A collision term (``type = "collision"``): ``pairs`` of ``[robot side, scene side]``, ``groups``
    (name -> links), ``self`` (the robot against itself), ``allow`` (pairs of links never checked, or
    ``"srdf"``: the robot's SRDF's ``<disable_collisions>``), ``margin`` (m, >= 0), ``hard`` (default true),
    ``max_distance`` (m, the query's culling distance, > margin), ``weight``, ``times``."""
    where = f"[costs.{name}]"
    if "margin" not in t:
        raise ValueError(f"{where} needs a margin (m): the smallest distance allowed")
    margin = number(t["margin"], f"{where} margin")
    if margin < 0:
        raise ValueError(f"{where} margin must be >= 0 (m), got {margin:g}")
    hard = t.get("hard", True)
    if not isinstance(hard, bool):
        raise ValueError(f"{where} hard must be true or false")
    if not hard and "weight" not in t:
        raise ValueError(f"{where} needs a weight (a soft collision term)")
    from raico.planning.costs import HARD_COLLISION_WEIGHT

    out: dict[str, Any] = {"type": "collision", "margin": margin, "hard": hard,
                           "weight": nonneg(t.get("weight", HARD_COLLISION_WEIGHT), f"{where} weight"),
                           "times": check_times(t.get("times", "all"), T, name),
                           "pairs": _name_pairs(t.get("pairs", []), f"{where} pairs")}
    groups = t.get("groups", {})
    if not isinstance(groups, dict) or not all(isinstance(v, list) and all(isinstance(x, str) for x in v)
                                               for v in groups.values()):
        raise ValueError(f"{where} groups must be a table {{group = [link, ...]}}")
    out["groups"] = {k: list(v) for k, v in groups.items()}
    self_ = t.get("self", False)
    if not isinstance(self_, bool):
        raise ValueError(f"{where} self must be true or false")
    out["self"] = self_
    allow = t.get("allow", [])
    out["allow"] = allow if allow == "srdf" else _name_pairs(allow, f"{where} allow")
    if not out["pairs"] and not self_:
        raise ValueError(f"{where} needs pairs (e.g. [[\"robot\", \"scene\"]]) or self = true")
    dmax = number(t.get("max_distance", margin + CULL), f"{where} max_distance")
    if not dmax > margin:
        raise ValueError(f"{where} max_distance must be > margin ({margin:g} m), got {dmax:g}")
    out["max_distance"] = dmax
    if "map" in t:
        if not isinstance(t["map"], str):
            raise ValueError(f"{where} map must be a string")
        out["map"] = t["map"]
    return out


def check_tol(v, name: str, parts: int):
    """A term's own tolerance of "task achieved": a number > 0 in its unit (m, rad); a term of two
    tolerance kinds (a frame placement's) a number (both parts) or ``[m, rad]``."""
    vals = v if isinstance(v, list) and parts == 2 else [v]
    if len(vals) not in (1, 2) or any(isinstance(x, bool) or not isinstance(x, (int, float)) or not 0 < x < math.inf
                                      for x in vals):
        raise ValueError(f"[costs.{name}] tol must be a number > 0 (m or rad"
                         + (", or [m, rad] for a frame placement" if parts == 2 else "") + f"), got {v!r}")
    return [float(x) for x in vals] if isinstance(v, list) else float(v)


# ------------------------------------------------------------------ descriptions (on the robot at q0)
def _map_name(t: dict, default: str) -> str:
    """The task map's name (``map``): terms on maps of one name share a plot and a path in the
    recordings; by default ``default`` (a frame's name, ``cog``, ``joints``, or the term's own name)."""
    return t.get("map", default)


def _with_resolved_frame(t: dict, name: str, robot) -> dict:
    return {**t, "frame": resolve_frame(robot, t["frame"], name)}


def describe_frame_position(name: str, t: dict, ctx: TermContext, steps, factor: float) -> dict:
    from raico.plants.taskmaps import FramePoints

    robot, q0 = ctx.robot, ctx.q0
    mname = _map_name(t, t["frame"])  # the frame as written (a joint's name stays the map's)
    t = _with_resolved_frame(t, name, robot)
    axes = tuple(t.get("axes", (0, 1, 2)))
    if not axes or any(a not in (0, 1, 2) for a in axes):
        raise ValueError(f"[costs.{name}] axes must be a list of 0, 1, 2")
    points = t.get("points")
    if "in_frame" in t:
        p = np.asarray(vector(t.get("target"), f"[costs.{name}] target", 3))
        X = robot.plant.GetFrameByName(resolve_frame(robot, t["in_frame"], name)).CalcPoseInWorld(robot.set_state(q0))
        target = (X.rotation().matrix() @ p + X.translation())[list(axes)]
    else:
        at_start = FramePoints(robot, t["frame"], points=points).value(q0)
        at_start = at_start.reshape(-1, 3)[:, list(axes)].reshape(-1) if points is not None \
            else at_start[list(axes)]
        target = _target(t, name, at_start)
    m = ob.frame_points(t["frame"], mname, axes=axes, points=points)
    return ob.via(name, m, target, steps, t["weight"] * factor, t.get("precision"), t.get("tol"))


def describe_frame_orientation(name: str, t: dict, ctx: TermContext, steps, factor: float) -> dict:
    t = _with_resolved_frame(t, name, ctx.robot)
    weight, precision, tol = t["weight"] * factor, t.get("precision"), t.get("tol")
    if "angle" in t:
        return ob.via(name, ob.roll(t["frame"], t.get("map", "roll")), [number(t.get("target"), f"[costs.{name}] target")],
                      steps, weight, precision, tol)
    m = ob.frame_rotation(t["frame"], _rotation(t, name, ctx.robot, ctx.q0), _map_name(t, name))
    return ob.via(name, m, np.zeros(3), steps, weight, precision, tol)


def describe_frame_placement(name: str, t: dict, ctx: TermContext, steps, factor: float) -> dict:
    t = _with_resolved_frame(t, name, ctx.robot)
    position = vector(t["position"], f"[costs.{name}] position", 3)
    m = ob.frame_placement(t["frame"], _rotation(t, name, ctx.robot, ctx.q0), position, _map_name(t, name))
    return ob.via(name, m, np.zeros(6), steps, t["weight"] * factor, t.get("precision"), t.get("tol"))


def describe_com(name: str, t: dict, ctx: TermContext, steps, factor: float) -> dict:
    from raico.plants.taskmaps import CenterOfMass

    axes = tuple(t.get("axes", (0, 1, 2)))
    at_start = CenterOfMass(ctx.robot).value(ctx.q0)[list(axes)]
    return ob.via(name, ob.cog(axes, _map_name(t, "cog")), _target(t, name, at_start), steps, t["weight"] * factor,
                  t.get("precision"), t.get("tol"))


def describe_posture(name: str, t: dict, ctx: TermContext, steps, factor: float) -> dict:
    idx = _joint_indices(ctx.robot, t.get("joints"), name)
    return ob.via(name, ob.joints(_map_name(t, "joints"), idx), _target(t, name, ctx.q0[idx]), steps,
                  t["weight"] * factor, t.get("precision"), t.get("tol"))


def describe_state(name: str, t: dict, ctx: TermContext, steps, factor: float) -> dict:
    robot, precision = ctx.robot, t.get("precision")
    if isinstance(precision, dict):  # {q = a, v = b}: one weight for the positions, one for the velocities
        refuse_unknown(precision, {"q", "v"}, f"[costs.{name}] precision")
        precision = [nonneg(precision.get("q", 1.0), f"[costs.{name}] precision.q")] * robot.n_q + \
            [nonneg(precision.get("v", 1.0), f"[costs.{name}] precision.v")] * robot.n_q
    x0 = np.concatenate([ctx.q0, np.zeros(robot.n_q)])
    target = x0 if t.get("target", "start") == "start" else \
        np.asarray(vector(t["target"], f"[costs.{name}] target", 2 * robot.n_q))
    return ob.state(name, target, steps, t["weight"] * factor, precision)


def describe_joint_limit(name: str, t: dict, ctx: TermContext, steps, factor: float) -> dict:
    robot = ctx.robot
    idx = _joint_indices(robot, t.get("joints"), name)
    lo = np.asarray(vector(t["lower"], f"[costs.{name}] lower", len(idx))) if "lower" in t else robot.lower[idx]
    hi = np.asarray(vector(t["upper"], f"[costs.{name}] upper", len(idx))) if "upper" in t else robot.upper[idx]
    keep = np.isfinite(lo) | np.isfinite(hi)
    A = np.vstack([np.eye(len(idx)), -np.eye(len(idx))])
    b = np.concatenate([np.where(np.isfinite(hi), hi, 1e9), np.where(np.isfinite(lo), -lo, 1e9)])
    rows = np.concatenate([keep, keep])
    return ob.inequality(name, ob.joints(_map_name(t, "joints"), idx), A[rows], b[rows], steps, t["weight"] * factor)


def describe_control(name: str, t: dict, ctx: TermContext, steps, factor: float) -> dict:
    return _control(name, t, ctx.robot, factor)


def describe_control_limit(name: str, t: dict, ctx: TermContext, steps, factor: float) -> dict:
    robot = ctx.robot
    effort, n_u = robot.effort[robot.actuated], len(robot.actuated)  # an underactuated robot's motors
    lo = vector(t["lower"], f"[costs.{name}] lower", n_u) if "lower" in t else (-effort).tolist()
    hi = vector(t["upper"], f"[costs.{name}] upper", n_u) if "upper" in t else effort.tolist()
    return ob.control_limit(lo, hi, t["weight"] * factor, name)


def describe_collision(name: str, t: dict, ctx: TermContext, steps, factor: float) -> dict:
    return _collision_term(name, t, ctx.problem, ctx.robot, steps, t["weight"] * factor)


# ------------------------------------------------------------------ helpers
def _rotation(t: dict, name: str, robot=None, q0=None) -> np.ndarray:
    if t.get("rotation") == "start":  # the frame's orientation at the start posture
        return robot.plant.GetFrameByName(t["frame"]).CalcPoseInWorld(robot.set_state(q0)).rotation().matrix()
    if "rotation" in t:
        R = np.asarray(t["rotation"], dtype=float)
        if R.shape != (3, 3) or not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ValueError(f"[costs.{name}] rotation must be a 3 x 3 rotation matrix")
        return R
    if "rpy" in t:
        from raico.plants.model_file import rpy_matrix

        return rpy_matrix(vector(t["rpy"], f"[costs.{name}] rpy", 3))
    return np.eye(3)


def resolve_frame(robot, frame: str, name: str) -> str:
    """The frame a term names: a frame of the plant, or a joint's name for the frame of its child
    link (Pinocchio's joint frames, which crocoddyl's examples name)."""
    plant = robot.plant
    if plant.HasFrameNamed(frame):
        return frame
    if plant.HasJointNamed(frame):
        return plant.GetJointByName(frame).child_body().body_frame().name()
    from raico.plants.model_file import closest_names, frame_names

    raise ValueError(f"[costs.{name}] frame '{frame}' is not in the robot: closest "
                     f"{closest_names(frame, frame_names(plant))}")


def _collision_term(name: str, t: dict, problem, robot, steps, weight: float) -> dict:
    """A collision term's description: its geometry pairs resolved on the robot's collision world
    (``raico.plants.scene.resolve_pairs``; unknown links, groups and objects refused)."""
    from raico.plants.scene import resolve_pairs, srdf_allowed

    scene = problem.doc.get("scene", [])
    world = _collision_world(robot.spec, scene)
    allow = t["allow"]
    if allow == "srdf":
        srdf = problem.doc["robot"].get("srdf")
        if srdf is None:
            from raico.plants.model_file import default_srdf

            found = default_srdf(Path(problem.doc["robot"]["file"]))
            srdf = None if found is None else str(found)
        if srdf is None:
            raise ValueError(f"[costs.{name}] allow = \"srdf\": the robot has no SRDF (give srdf in [robot])")
        allow = srdf_allowed(srdf)
    else:
        for link in (ln for pair in allow for ln in pair):
            if not world.plant.HasBodyNamed(link):
                from raico.plants.model_file import closest_names

                raise ValueError(f"[costs.{name}] allow: unknown link '{link}': closest "
                                 f"{closest_names(link, world.robot_links())}")
    groups = t["groups"]
    for g, links in groups.items():
        for link in links:
            if link not in groups and link not in world.robot_links() and link != "robot":
                from raico.plants.model_file import closest_names

                raise ValueError(f"[costs.{name}] groups.{g}: unknown link '{link}': closest "
                                 f"{closest_names(link, world.robot_links())}")
    pairs = resolve_pairs(world, t["pairs"], groups, t["self"], allow, f"[costs.{name}]")
    if not pairs:
        raise ValueError(f"[costs.{name}]: no pair of geometries to check (the links or objects named carry none)")
    m = {"map": "distances", "name": t.get("map", name), "scene": scene, "pairs": [list(p) for p in pairs],
         "max_distance": t["max_distance"]}
    return ob.collision(name, m, t["margin"], t["hard"], steps, weight)


def _collision_world(spec, scene: list[dict]):
    """The collision world of ``spec`` and ``scene`` for resolving names (one per process and content)."""
    key = json.dumps([spec.to_dict(), scene], sort_keys=True)
    world = _WORLDS.get(key)
    if world is None:
        from raico.plants.scene import CollisionWorld

        world = _WORLDS[key] = CollisionWorld(spec, scene)
    return world


_WORLDS: dict[str, Any] = {}


def _control(name: str, t: dict, robot, factor: float) -> dict:
    """A control term's description: ``target`` numbers (N m, or rad/s^2) or ``"gravity"`` (the torque
    that holds the robot still, for torque controls only); a list ``weight`` weighs each joint: the
    term's weight is the largest, the list over it its precision."""
    w = t["weight"]
    precision = None
    if isinstance(w, list):
        w = np.asarray(vector(w, f"[costs.{name}] weight", len(robot.actuated)))
        top = float(w.max())
        precision, w = (w / top if top > 0 else np.ones_like(w)).tolist(), top
    d = ob.control(w * factor, name)
    if t.get("target") == "gravity":
        d.update(target="gravity", controls="torque")
    elif "target" in t:
        d["target"] = vector(t["target"], f"[costs.{name}] target", len(robot.actuated))
    if precision is not None:
        d["precision"] = precision
    return d


def _target(t: dict, name: str, value_at_start: np.ndarray) -> np.ndarray:
    dim = value_at_start.size
    target = t.get("target")
    if target is None or target == "start":
        base = value_at_start if target == "start" else np.zeros(dim)
        return base.copy()
    try:
        x = np.asarray(target, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"[costs.{name}] target must be numbers or \"start\", got {target!r}") from None
    if not np.all(np.isfinite(x)):
        raise ValueError(f"[costs.{name}] target must be finite")
    if x.size != dim:
        raise ValueError(f"[costs.{name}] target has {x.size} values, expected {dim}")
    return value_at_start + x if t.get("relative") == "start" else x


def _joint_indices(robot, joints, name: str) -> list[int]:
    if joints is None:
        return list(range(robot.n_q))
    if not isinstance(joints, list) or not all(isinstance(j, str) for j in joints):
        raise ValueError(f"[costs.{name}] joints must be a list of joint names")
    from raico.plants.model_file import closest_names

    out = []
    for j in joints:
        if j not in robot.joint_names:
            raise ValueError(f"[costs.{name}] joint '{j}' is not a planning joint: closest "
                             f"{closest_names(j, robot.joint_names)}")
        out.append(robot.joint_names.index(j))
    return out
