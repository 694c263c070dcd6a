"""The kinds of cost terms in three tables, each row a kind with its columns, from the problem file's
TOML key down to the compiled case.

- :data:`COST_KINDS` (rows :class:`CostKind`): a problem file's ``[costs.NAME] type``: its keys, its
  parser and describer (``raico.planning.problem_terms``), the description terms and task maps it gives;
- :func:`term_kinds` (rows :class:`TermKind`): a description's ``"term"``: its class
  (``raico.planning.costs``), side, builder and crocoddyl residual;
- :data:`MAP_KINDS` (rows :class:`MapKind`): a description's ``"map"``: its class (``raico.plants.taskmaps``),
  builder, compiled case (``raico/planning/task_messages.c``), crocoddyl residual, tolerance kinds of "task
  achieved" (``raico.planning.achieved``) and plot labels (``raico.pipeline.recordings.tasks``).

A row is looked up by key (:func:`cost_kind`, :func:`term_named`, :func:`kind_named`) or by the class of
a built object (:func:`kind_of_term`, :func:`kind_of_map`). A new cost kind is a row of
:data:`COST_KINDS` with its two functions; where it needs a new task map or cost term, that class and
its row below (docs/layout.md walks through one).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import numpy as np

from raico.plants.scene import ROBOT_PREFIX, CollisionWorld, SignedDistances
from raico.plants.taskmaps import (
    CenterOfMass,
    FramePlacementError,
    FramePoints,
    FrameRotationError,
    JointPositions,
    RollAngle,
)


class MessageKind(IntEnum):
    """What a compiled task term evaluates: ``enum message_kind`` of ``raico/planning/task_messages.c``
    (the same values; tests/planning/test_kernels.py reads the C enum and compares)."""

    FRAME_POINTS = 0      # FramePoints
    CENTER_OF_MASS = 1    # CenterOfMass
    ROLL = 2              # RollAngle
    JOINTS = 3            # JointPositions (phi = S q)
    STATE_TARGET = 4      # StateTarget on the whole state
    FRAME_ROTATION = 5    # FrameRotationError (log3, Jlog3)
    FRAME_PLACEMENT = 6   # FramePlacementError (log6, Jlog6)
    GRAVITY = 7           # ControlGravity's state part: g(q), the target u_t (the nominal controls)


TASK_MAX_ROWS = 64        # TMAX of task_messages.c: rows of one task map's full output


@dataclass(frozen=True)
class MapKind:
    """One row of the task-map table. Columns:

    - ``key``: the description's ``"map"`` value (``raico.planning.objective``); ``cls``: the task-map class;
    - ``build(robot, d) -> TaskMap`` from a description ``d``;
    - ``compile(tm, vt, kernels, arr) -> bool``: fills the map fields of a compiled term (``vt``, a
      ``raico.planning.kernels._VTerm``; ``kernels``: the robot's tree kernels, ``None`` for a map that needs
      none; ``arr(a, dtype)`` keeps ``a`` alive and gives its address); ``False`` where this instance
      does not fit the kernel (then the Python messages run); ``None``: no compiled counterpart (a new
      one is a :class:`MessageKind` with its branch in ``task_messages.c`` and a function here);
    - ``tree``: whether the compiled map reads the robot's tree kernels (the frame maps, the CoM);
    - ``crocoddyl``: the name of the function of ``raico.planning.crocoddyl.costs`` that gives the
      via-point's crocoddyl residuals (``None``: not expressible);
    - ``labels(m, dim, name, joint_names) -> (component names, coordinates per point, unit, angle?)``
      of a map description ``m`` for the plots;
    - ``tolerance``: the kinds of "task achieved" a via-point on it is judged by
      (``raico.planning.achieved.TASK_TOLERANCES``), each with the rows of the map it covers; ``()``: none.
    """

    key: str
    cls: type
    build: Callable[[Any, dict], Any]
    compile: Callable[..., bool] | None
    tree: bool
    crocoddyl: str | None
    labels: Callable[[dict, int, str, list], tuple[list[str], int, str, bool]]
    tolerance: tuple[tuple[str, slice], ...] = ()


ALL = slice(None)  # every row of a map


# -- compiled counterparts: the map fields of a compiled term -------------------------------------
def _rows_fit(kept, rows: int, dim: int) -> bool:
    """The rows a term keeps lie in its map's full output (``rows``), and that output fits the kernel."""
    return (rows <= TASK_MAX_ROWS and np.shape(kept) == (dim,) and min(kept) >= 0
            and max(kept) < rows)


def _compile_frame_points(tm: FramePoints, vt, k, arr) -> bool:
    vt.kind, vt.npts = MessageKind.FRAME_POINTS, len(tm.points)
    vt.body = k.tree.body(tm.body_name)
    vt.R_BF, vt.p_BF, vt.pts = arr(tm.frame_rotation), arr(tm.frame_offset), arr(tm.points)
    vt.rows = arr(tm.rows, np.int64)
    return _rows_fit(tm.rows, 3 * len(tm.points), tm.dim)


def _compile_com(tm: CenterOfMass, vt, k, arr) -> bool:
    vt.kind, vt.rows = MessageKind.CENTER_OF_MASS, arr(tm.axes, np.int64)
    return _rows_fit(tm.axes, 3, tm.dim)


def _compile_roll(tm: RollAngle, vt, k, arr) -> bool:
    vt.kind, vt.body = MessageKind.ROLL, k.tree.body(tm.body_name)
    vt.R_BF, vt.rows = arr(tm.frame_rotation), arr([0], np.int64)
    return True


def _compile_joints(tm: JointPositions, vt, k, arr) -> bool:
    vt.kind, vt.S = MessageKind.JOINTS, arr(tm.S)
    return True


def _compile_frame_pose(tm, vt, k, arr) -> bool:
    """A frame's orientation (3 rows) or placement (6 rows) error from its target pose."""
    vt.kind = MessageKind.FRAME_ROTATION if isinstance(tm, FrameRotationError) else MessageKind.FRAME_PLACEMENT
    vt.body = k.tree.body(tm.body_name)
    vt.R_BF, vt.p_BF = arr(tm.frame_rotation), arr(tm.frame_offset)
    vt.R_target = arr(tm.R_target)
    vt.p_target = arr(getattr(tm, "p_target", np.zeros(3)))
    vt.rows = arr(np.arange(tm.dim), np.int64)
    return True


# -- plot labels ------------------------------------------------------------------------------------
def _axes_labels(m, dim, name, joint_names):
    axes = [("x", "y", "z")[a] for a in m.get("axes", (0, 1, 2))]
    return axes, len(axes), "m", False


def _joint_labels(m, dim, name, joint_names):
    idx = m.get("indices") or range(len(joint_names))
    return [joint_names[i] for i in idx], dim, "rad", False


def default_labels(m, dim: int, name: str, joint_names) -> tuple[list[str], int, str, bool]:
    """Labels of a map without a row (or without a description): ``name[i]``, no unit."""
    return [f"{name}[{i}]" for i in range(dim)], dim, "", False


def _distance_labels(m, dim, name, joint_names):
    return [f"{a.removeprefix(ROBOT_PREFIX)} | {b.removeprefix(ROBOT_PREFIX)}" for a, b in m["pairs"]], dim, "m", False


def _build_distances(robot, d: dict) -> SignedDistances:
    """The signed distances of a description's geometry pairs, on a collision world of the robot's model
    file and the description's scene (``raico.plants.scene``)."""
    if robot.spec is None:
        raise ValueError(f"collision terms need a robot loaded from a model file; {robot.name} is not")
    world = CollisionWorld(robot.spec, d["scene"])
    unknown = [n for p in d["pairs"] for n in p if n not in world.geometries]
    if unknown:
        raise ValueError(f"collision map '{d['name']}': geometry '{unknown[0]}' is not in the collision world")
    return SignedDistances(robot, world, [tuple(p) for p in d["pairs"]], d["max_distance"], name=d["name"])


# -- the table --------------------------------------------------------------------------------------
MAP_KINDS: tuple[MapKind, ...] = (
    MapKind("frame_points", FramePoints,
            lambda r, d: FramePoints(r, d["frame"], points=d.get("points"), axes=tuple(d["axes"]), name=d["name"]),
            _compile_frame_points, True, "via_frame_points", _axes_labels, (("position", ALL),)),
    MapKind("roll", RollAngle, lambda r, d: RollAngle(r, d["frame"], name=d["name"]),
            _compile_roll, True, "via_roll",
            lambda m, dim, name, jn: ([f"{name} (unwrapped)"], 1, "rad", True), (("orientation", ALL),)),
    MapKind("cog", CenterOfMass, lambda r, d: CenterOfMass(r, axes=tuple(d["axes"]), name=d["name"]),
            _compile_com, True, "via_com", _axes_labels, (("com", ALL),)),
    MapKind("joints", JointPositions, lambda r, d: JointPositions(r.n_q, d.get("indices"), name=d["name"]),
            _compile_joints, False, "via_joints", _joint_labels, (("posture", ALL),)),
    MapKind("frame_rotation", FrameRotationError,     # the rotation vector of R*^T R
            lambda r, d: FrameRotationError(r, d["frame"], d["rotation"], name=d["name"]),
            _compile_frame_pose, True, "via_frame_pose",
            lambda m, dim, name, jn: (["rx", "ry", "rz"], 3, "rad", False), (("orientation", ALL),)),
    MapKind("distances", SignedDistances, _build_distances, None, False, None, _distance_labels),
    MapKind("frame_placement", FramePlacementError,   # log6: translation part (m) then rotation vector (rad)
            lambda r, d: FramePlacementError(r, d["frame"], d["rotation"], d["translation"], name=d["name"]),
            _compile_frame_pose, True, "via_frame_pose",
            lambda m, dim, name, jn: (["vx", "vy", "vz", "rx", "ry", "rz"], 6, "m, rad", False),
            (("position", slice(0, 3)), ("orientation", slice(3, None)))),
)
_BY_CLASS = {k.cls: k for k in MAP_KINDS}
_BY_KEY = {k.key: k for k in MAP_KINDS}


def kind_of_map(tm) -> MapKind | None:
    """The row of the task map ``tm``'s class (its exact class: a subclass may compute something
    else), or ``None``."""
    return _BY_CLASS.get(type(tm))


def kind_named(key: str | None) -> MapKind | None:
    """The row of a description's ``"map"`` key, or ``None``."""
    return _BY_KEY.get(key)


def map_keys() -> list[str]:
    """The description keys of the task-map kinds."""
    return [k.key for k in MAP_KINDS]


# -- cost terms --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TermKind:
    """One row of the cost-term table: ``key`` (the description's ``"term"``), ``cls``, ``side``
    (``"state"``: on ``x_t``, ``"control"``: on ``u_t``, ``"joint"``: on both), ``build(robot, d)``
    (``None``: built elsewhere, see the row) and ``crocoddyl``, the name of the function of
    ``raico.planning.crocoddyl.costs`` that gives its crocoddyl ``(residual, activation)`` pairs
    (``raico.planning.objective.build_term`` and ``raico.planning.crocoddyl.costs.cost_items`` read it)."""

    key: str
    cls: type
    side: str
    build: Callable[[Any, dict], Any] | None
    crocoddyl: str | None


def _times(t) -> list[int]:
    """Steps as described: a list, or ``{"from": a, "to": b}`` (every step a..b)."""
    return list(range(int(t["from"]), int(t["to"]) + 1)) if isinstance(t, dict) else list(t)


def _term_rows() -> tuple[TermKind, ...]:
    from raico.planning.costs import (
        Collision,
        ControlCost,
        ControlGravity,
        ControlLimit,
        StateTarget,
        TaskInequality,
        ViaPoint,
    )

    def taskmap(robot, d):
        row = kind_named(d["map"]["map"])
        if row is None:
            raise ValueError(f"unknown task map kind {d['map']['map']!r}: valid kinds are {', '.join(map_keys())}")
        return row.build(robot, d["map"])

    return (
        TermKind("via", ViaPoint, "state", lambda r, d: ViaPoint(
            taskmap(r, d), d["target"], _times(d["times"]), d["weight"], d.get("precision"), name=d["name"],
            tol=d.get("tol")), "items_via"),
        TermKind("inequality", TaskInequality, "state", lambda r, d: TaskInequality(
            taskmap(r, d), d["A"], d["b"], _times(d["times"]), d["weight"], name=d["name"]), "items_joint_bounds"),
        TermKind("collision", Collision, "state", lambda r, d: Collision(
            taskmap(r, d), d["margin"], _times(d["times"]), d["weight"], d.get("hard", True), name=d["name"]),
            "items_collision"),
        TermKind("state", StateTarget, "state", lambda r, d: StateTarget(
            d["target"], _times(d["times"]), d["weight"], d.get("precision"), name=d["name"]), "items_state"),
        TermKind("control", ControlCost, "control", lambda r, d: ControlCost(
            d["weight"], target=d.get("target"), name=d["name"], precision=d.get("precision")), "items_control"),
        TermKind("control_limit", ControlLimit, "control", lambda r, d: ControlLimit(
            d["lower"], d["upper"], d["weight"], name=d["name"]), "items_control_limit"),
        # toward gravity: a joint term on (x_t, u_t), built by raico.planning.objective.build_terms from a
        # "control" description whose target is "gravity" (it needs the horizon): no builder here;
        # compiled: MessageKind.GRAVITY (its state part, raico.planning.kernels.compile_task_set)
        TermKind("control@gravity", ControlGravity, "joint", None, "items_control_gravity"),
    )


_TERMS: tuple[TermKind, ...] | None = None


def term_kinds() -> tuple[TermKind, ...]:
    """The cost-term table (built on first use: ``raico.planning.costs`` imports nothing from here)."""
    global _TERMS
    if _TERMS is None:
        _TERMS = _term_rows()
    return _TERMS


def term_named(key: str) -> TermKind | None:
    """The row of a description's ``"term"`` key that builds it, or ``None``."""
    return next((k for k in term_kinds() if k.key == key and k.build is not None), None)


def kind_of_term(term) -> TermKind | None:
    """The row of the cost term ``term``'s exact class, or ``None``."""
    return next((k for k in term_kinds() if type(term) is k.cls), None)


# -- a problem file's cost terms ----------------------------------------------------------------------
@dataclass(frozen=True)
class CostKind:
    """One row of the problem-file table: ``type`` (``[costs.NAME] type``), ``keys`` (those it takes;
    others are refused), ``check`` and ``describe``: the names of its functions in
    ``raico.planning.problem_terms`` (``check(name, t, T)``: the term as written, checked, in canonical form;
    ``describe(name, t, ctx, steps, factor)``: its description on the robot), ``terms`` and ``maps``: the
    keys of the rows of :func:`term_kinds` and :data:`MAP_KINDS` its descriptions use (their classes,
    compiled cases, crocoddyl residuals, tolerance kinds and labels). A term without ``times`` in its
    keys is on the controls (every step). ``geometry``: the kind needs the robot's collision geometry,
    which only a model file carries (a built-in plant has none)."""

    type: str
    keys: frozenset[str]
    check: str
    describe: str
    terms: tuple[str, ...]
    maps: tuple[str, ...] = ()
    geometry: bool = False

    @property
    def tolerance_parts(self) -> int:
        """How many tolerances a term of this kind may state (``tol``; a frame placement's two: m, rad)."""
        return max((len(kind_named(m).tolerance) for m in self.maps), default=0)


_COMMON = frozenset({"type", "weight", "times", "map"})
_VIA = _COMMON | {"precision", "tol"}
COST_KINDS: tuple[CostKind, ...] = (
    CostKind("frame_position", _VIA | {"frame", "target", "axes", "points", "relative", "in_frame", "moving"},
             "check_frame_position", "describe_frame_position", ("via",), ("frame_points",)),
    CostKind("frame_orientation", _VIA | {"frame", "rotation", "rpy", "angle", "target"},
             "check_frame_orientation", "describe_frame_orientation", ("via",), ("frame_rotation", "roll")),
    CostKind("frame_placement", _VIA | {"frame", "position", "rotation", "rpy"},
             "check_frame_placement", "describe_frame_placement", ("via",), ("frame_placement",)),
    CostKind("com", _VIA | {"target", "axes", "relative"}, "check_task", "describe_com", ("via",), ("cog",)),
    CostKind("posture", _VIA | {"joints", "target", "relative"}, "check_task", "describe_posture", ("via",),
             ("joints",)),
    CostKind("state", _COMMON | {"target", "precision"}, "check_task", "describe_state", ("state",)),
    CostKind("control", frozenset({"type", "weight", "target"}), "check_control", "describe_control",
             ("control", "control@gravity")),
    CostKind("control_limit", frozenset({"type", "weight", "lower", "upper"}), "check_task",
             "describe_control_limit", ("control_limit",)),
    CostKind("joint_limit", _COMMON | {"joints", "lower", "upper"}, "check_task", "describe_joint_limit",
             ("inequality",), ("joints",)),
    CostKind("collision", _COMMON | {"pairs", "groups", "self", "allow", "margin", "hard", "max_distance"},
             "check_collision", "describe_collision", ("collision",), ("distances",), geometry=True),
)
_BY_TYPE = {k.type: k for k in COST_KINDS}


def cost_kind(type_: str | None) -> CostKind | None:
    """The row of a problem file's ``[costs.NAME] type``, or ``None``."""
    return _BY_TYPE.get(type_ or "")
