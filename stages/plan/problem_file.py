"""Problem files: a robot, a horizon, dynamics and named cost terms, written in TOML.

A problem file states a planning problem the way the field does (crocoddyl's action models,
EXOTica's task maps): a robot (a built-in plant, or a model file, :mod:`plants.model_file`), the
horizon ``T`` steps of ``dt`` seconds, the dynamics model and its integrator, and cost terms, each a
task map with a target, a weight and the steps it applies at::

    name = "kinova-reach"
    [robot]
    file = "package://example-robot-data/robots/kinova_description/robots/kinova.urdf"
    start = "arm_up"                  # an SRDF posture, or {joint = value, ...}
    [horizon]
    T = 100
    dt = 0.01
    [dynamics]
    model = "analytic"                # or "pseudo" (controls are accelerations)
    [costs]
    convention = "crocoddyl"          # weight/2 ||r||^2, times dt on steps before T
    [costs.goal]
    type = "frame_placement"
    frame = "j2s6s200_end_effector"
    position = [0.6, 0.2, 0.5]
    times = "running"                 # steps 0..T-1; "last": T; "all": 1..T; or a list of steps
    weight = 1.0

Cost term types (``type``) and their keys:

- ``frame_position``: ``frame``, ``target`` (3, or one per ``axes``), optional ``axes``,
  ``points`` (points fixed in the frame, k x 3; the target then k x dim), ``precision``;
- ``frame_orientation``: ``frame`` and ``rotation`` (3 x 3, or ``"start"``: the frame's at ``q0``)
  or ``rpy`` (rad): the rotation vector of ``R*^T R(q)``; or ``angle = "roll"`` with a scalar ``target`` (the thesis's roll about the
  hand axis, ``atan2(y_E . z_W, z_E . z_W)``);
- ``frame_placement``: ``frame``, ``position`` and ``rotation``/``rpy``: ``log6(M*^-1 M(q))``, as
  crocoddyl's frame-placement residual;
- ``com``: ``target`` (3, or one per ``axes``), ``precision``;
- ``posture``: ``joints`` (names; default all), ``target`` (values or ``"start"``);
- ``state``: ``target`` (``2 n`` values or ``"start"``: the start posture at rest), ``precision``
  (``2 n`` values, or ``{q = a, v = b}``);
- ``control``: ``weight`` (a number, or one per joint), optional ``target`` (n values, or ``"gravity"``:
  the torque that holds the robot still, crocoddyl's ``ResidualModelControlGrav``; torque controls only);
- ``control_limit``: ``lower``/``upper`` (default: the model's effort limits), soft, torques only;
- ``joint_limit``: soft position limits (default: the model's), ``lower``/``upper``.

Every term may name its task map (``map``, default: the frame's name, ``cog``, ``joints`` or the
term's name): terms on maps of one name share a plot and a path in the recordings. A via-point term
(``frame_position``, ``frame_orientation``, ``frame_placement``, ``com``, ``posture``) may set its
tolerance of "task achieved" in its unit, ``tol`` (m or rad; a placement ``[m, rad]``; default its
kind's, ``planning.costs.TASK_TOLERANCES``).

A built-in plant (``plant``) takes only ``start``: ``"zero"`` (every joint at 0, clipped to its
range) or ``{joint = value, ...}`` (the others at the plant's default posture). A model file's robot
may state its facts as the built-in plants do in ``plants/models/NAME.toml`` (``coupled``,
``end_effectors``, ``hands``, ``feet``, ``sole``, ``order``, ``execution`` and ``learn``;
:class:`plants.model_file.RobotSpec`).

``[[scene]]`` (optional): objects around the robot, each with a ``name``, a ``type`` (``box`` ``size``,
``sphere`` ``radius``, ``cylinder`` and ``capsule`` ``radius`` and ``length``, ``mesh`` ``file`` and ``scale``:
its convex hull, ``file``: a URDF/SDF world file) and a ``pose`` ``[x, y, z, roll, pitch, yaw]``
(:mod:`plants.scene`). A ``collision`` term keeps geometry pairs apart: ``pairs`` of ``[robot side, scene
side]`` (a link, a group of ``groups``, or ``"robot"``; an object, or ``"scene"``), ``self = true`` (every two
links no joint connects, less ``allow``: pairs of links, or ``"srdf"``), ``margin`` (m), ``hard`` (default
true: ``d >= margin``; a stiff penalty of weight ``planning.costs.HARD_COLLISION_WEIGHT`` unless ``weight``
says otherwise, until a solver takes it as a constraint), ``max_distance`` (m, pairs farther are not queried;
default ``margin + CULL``).

``[achieved]`` (optional): how an execution is judged achieved where the terms' own errors do not say
it: ``joint`` ends within ``tol`` (rad) of ``angle`` (rad), wrapped (the pendulum's swing-up), and, where
``velocity_tol`` (rad/s) is stated, with its speed within it (a pole that passes upright is not balanced).

Targets: ``target = "start"`` is the map's value at the start posture ``q0``; ``relative =
"start"`` adds that value to the target; ``in_frame = "F"`` reads a 3-D position target in frame
F's pose at ``q0`` (before ``axes`` selects coordinates). ``times``: a list of steps in ``[0, T]``,
``{from = a, to = b}`` (steps a..b), ``"last"`` (``[T]``), ``"all"`` (``1..T``), ``"running"``
(``0..T-1``) or ``"every"`` (``0..T``, crocoddyl's running and terminal nodes). Weights: with the
``raico`` convention (default) a term costs ``w ||r||_C^2`` at each of its steps (thesis eq. 3.7);
with ``crocoddyl`` it costs ``w/2 ||r||^2``, times ``dt`` on steps before ``T``, so crocoddyl's
problems are written with crocoddyl's numbers.

Unknown keys, names, shapes, negative weights and steps past ``T`` are refused
(``ValueError``, one line with the valid choices).
"""

from __future__ import annotations

import hashlib
import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from planning import objective as ob
from plants.scene import COMMON_KEYS as SCENE_COMMON
from plants.scene import SHAPES

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ROOT / "problems"
TOP_KEYS = {"name", "description", "robot", "horizon", "dynamics", "costs", "achieved", "scene"}
ACHIEVED_KEYS = {"joint", "angle", "tol", "velocity_tol"}
ROBOT_FACTS = {"order", "coupled", "end_effectors", "hands", "feet", "sole", "execution", "learn", "unactuated",
               "gravity"}
ROBOT_KEYS = {"plant", "file", "packages", "weld", "weld_pose", "locked", "start", "srdf", "armature", "limits",
              "true"} | ROBOT_FACTS
TRUE_KEYS = {"payload", "mass_scale", "friction"}  # [robot.true]: the executed robot's differences from its file
PAYLOAD_KEYS = {"frame", "mass", "com"}
HORIZON_KEYS = {"T", "dt"}
DYNAMICS_KEYS = {"model", "integrator", "substeps"}
# dynamics model -> integrator -> raico's dynamics name (plants.dynamics_registry)
INTEGRATORS = {"pseudo": {"backward-euler": "pseudo", "euler": "pseudo-euler", "heun": "pseudo-heun"},
               "analytic": {"semi-implicit-euler": "analytic"}}
CONVENTIONS = ("raico", "crocoddyl")
TIMES = ("last", "all", "running", "every")
COMMON = {"type", "weight", "times", "map"}
TERM_KEYS = {
    "frame_position": COMMON | {"frame", "target", "axes", "points", "precision", "relative", "in_frame", "tol"},
    "frame_orientation": COMMON | {"frame", "rotation", "rpy", "angle", "target", "precision", "tol"},
    "frame_placement": COMMON | {"frame", "position", "rotation", "rpy", "precision", "tol"},
    "com": COMMON | {"target", "axes", "precision", "relative", "tol"},
    "posture": COMMON | {"joints", "target", "precision", "relative", "tol"},
    "state": COMMON | {"target", "precision"},
    "control": {"type", "weight", "target"},
    "control_limit": {"type", "weight", "lower", "upper"},
    "joint_limit": COMMON | {"joints", "lower", "upper"},
    "collision": {"type", "weight", "times", "map", "pairs", "groups", "self", "allow", "margin", "hard",
                  "max_distance"},
}
SCENE_KEYS = {kind: SCENE_COMMON | keys for kind, keys in SHAPES.items()}   # [[scene]] by type (plants.scene)
CULL = 0.05   # m: a collision term's default max_distance beyond its margin (pairs farther are not queried)
ANGLES = ("roll",)


def _refuse_unknown(keys, valid, where: str) -> None:
    unknown = sorted(set(keys) - set(valid))
    if unknown:
        raise ValueError(f"{where}: unknown key '{unknown[0]}': valid keys are {', '.join(sorted(valid))}")


@dataclass(frozen=True)
class ProblemFile:
    """A parsed problem file: ``doc`` is its canonical content (JSON-able, the cache key's part)."""

    doc: dict

    @property
    def name(self) -> str:
        return self.doc["name"]

    @property
    def T(self) -> int:
        return int(self.doc["horizon"]["T"])

    @property
    def dt(self) -> float:
        return float(self.doc["horizon"]["dt"])

    @property
    def dynamics(self) -> str:
        d = self.doc["dynamics"]
        return INTEGRATORS[d["model"]][d["integrator"]]

    @property
    def substeps(self) -> int:
        """Model steps per control step of ``dt`` (``plants.dynamics.SubstepDynamics``; 1: one)."""
        return int(self.doc["dynamics"].get("substeps", 1))

    @property
    def plant(self) -> str | None:
        return self.doc["robot"].get("plant")

    @property
    def achieved(self) -> dict | None:
        """The task's own criterion of an execution achieved (``[achieved]``: joint, angle, tol), or None."""
        return self.doc.get("achieved")

    @property
    def plant_start(self) -> str | dict | None:
        """A built-in plant's start posture in place of its default (``"zero"`` or {joint: rad}), else None."""
        return self.doc["robot"].get("start") if self.plant is not None else None

    @property
    def robot_label(self) -> str:
        """A short name of the robot for tables: the built-in plant, or the model file's stem."""
        return self.plant or Path(self.doc["robot"]["file"]).stem

    def robot_spec(self):
        """The :class:`plants.model_file.RobotSpec` of a model-file robot, the planner's model (None for a
        built-in plant)."""
        if self.plant is not None:
            return None
        from plants.model_file import RobotSpec

        return RobotSpec.from_dict(self.doc["robot"]).planning

    def true_spec(self):
        """The spec of the robot that is babbled on and executed: the model file's with ``[robot.true]``'s
        changes, or None when the problem states none (then the file's robot is the true one)."""
        if self.plant is not None or not self.doc["robot"].get("true"):
            return None
        from plants.model_file import RobotSpec

        return RobotSpec.from_dict(self.doc["robot"])

    def canonical(self) -> str:
        return json.dumps(self.doc, sort_keys=True, separators=(",", ":"))

    def digest(self) -> str:
        return hashlib.sha256(self.canonical().encode()).hexdigest()[:16]


# ------------------------------------------------------------------ reading
def read_problem(path: str | Path) -> ProblemFile:
    """Parse and check a problem file (``ValueError`` with one line on any fault)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"problem file not found: {path}")
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"problem file {path.name}: not valid TOML: {e}") from None
    return ProblemFile(normalize(raw, path.resolve().parent, path.stem))


def normalize(raw: dict, base: Path, default_name: str) -> dict:
    """The canonical content of a problem file (paths resolved, defaults filled, keys checked)."""
    _refuse_unknown(raw, TOP_KEYS, "problem file")
    for key in ("robot", "horizon", "costs"):
        if not isinstance(raw.get(key), dict):
            raise ValueError(f"problem file: missing table [{key}]")
    doc: dict[str, Any] = {"name": str(raw.get("name", default_name)),
                           "description": str(raw.get("description", ""))}
    doc["robot"] = _robot(raw["robot"], base)
    if "scene" in raw:
        doc["scene"] = _scene(raw["scene"], base, doc["robot"])
    if "achieved" in raw:
        doc["achieved"] = _achieved(raw["achieved"])
    h = raw["horizon"]
    _refuse_unknown(h, HORIZON_KEYS, "[horizon]")
    T, dt = h.get("T"), h.get("dt")
    if not isinstance(T, int) or not 1 <= T <= 100000:
        raise ValueError(f"[horizon] T must be an integer in [1, 100000], got {T!r}")
    if not isinstance(dt, (int, float)) or not 0 < dt <= 1.0:
        raise ValueError(f"[horizon] dt must be in (0, 1] s, got {dt!r}")
    doc["horizon"] = {"T": T, "dt": float(dt)}
    d = raw.get("dynamics", {})
    _refuse_unknown(d, DYNAMICS_KEYS, "[dynamics]")
    model = d.get("model", "pseudo")
    if model not in INTEGRATORS:
        raise ValueError(f"[dynamics] unknown model '{model}': choose one of {', '.join(INTEGRATORS)}")
    integ = d.get("integrator", next(iter(INTEGRATORS[model])))
    if integ not in INTEGRATORS[model]:
        raise ValueError(f"[dynamics] unknown integrator '{integ}' for {model}: choose one of "
                         f"{', '.join(INTEGRATORS[model])}")
    doc["dynamics"] = {"model": model, "integrator": integ}
    substeps = d.get("substeps", 1)
    if isinstance(substeps, bool) or not isinstance(substeps, int) or not 1 <= substeps <= 1000:
        raise ValueError(f"[dynamics] substeps must be an integer in [1, 1000], got {substeps!r}")
    if substeps != 1:  # the model stepped substeps times per control step (kept out of the doc at 1)
        if model == "pseudo":
            raise ValueError("[dynamics] substeps: for the analytic model (and the learned one) only")
        doc["dynamics"]["substeps"] = substeps
    costs = dict(raw["costs"])
    convention = costs.pop("convention", "raico")
    if convention not in CONVENTIONS:
        raise ValueError(f"[costs] unknown convention '{convention}': choose one of {', '.join(CONVENTIONS)}")
    if not costs:
        raise ValueError("[costs]: no cost term (add [costs.NAME] with a type)")
    terms = {}
    for name, term in costs.items():
        if not isinstance(term, dict):
            raise ValueError(f"[costs] '{name}' must be a table [costs.{name}] with a type")
        terms[name] = _term(name, term, T)
        if term.get("type") == "collision" and "plant" in doc["robot"]:
            raise ValueError(f"[costs.{name}] collision terms need a robot from a model file (file), "
                             f"not the built-in plant '{doc['robot']['plant']}'")
    doc["costs"] = {"convention": convention, "terms": terms}
    return doc


def _achieved(a) -> dict:
    """``[achieved]``: how an execution of the task is judged achieved, where the terms' own errors do not say it:
    joint ``joint`` ends within ``tol`` (rad) of ``angle`` (rad), the difference wrapped to (-pi, pi], and with a
    speed within ``velocity_tol`` (rad/s) where it is stated."""
    if not isinstance(a, dict):
        raise ValueError("[achieved] must be a table {joint, angle, tol}")
    _refuse_unknown(a, ACHIEVED_KEYS, "[achieved]")
    if not isinstance(a.get("joint"), str) or "angle" not in a or "tol" not in a:
        raise ValueError("[achieved] needs joint (a name), angle (rad) and tol (rad)")
    tol = _number(a["tol"], "[achieved] tol")
    if tol <= 0:
        raise ValueError(f"[achieved] tol must be > 0 (rad), got {tol}")
    out = {"joint": a["joint"], "angle": _number(a["angle"], "[achieved] angle"), "tol": tol}
    if "velocity_tol" in a:
        vtol = _number(a["velocity_tol"], "[achieved] velocity_tol")
        if vtol <= 0:
            raise ValueError(f"[achieved] velocity_tol must be > 0 (rad/s), got {vtol}")
        out["velocity_tol"] = vtol
    return out


def _robot(r: dict, base: Path) -> dict:
    _refuse_unknown(r, ROBOT_KEYS, "[robot]")
    if ("plant" in r) == ("file" in r):
        raise ValueError("[robot]: give either plant (a built-in: pendulum, cartpole, arm5, biorob, nao) or file (a model file)")
    if "plant" in r:
        from plants.robots import PLANTS

        if r["plant"] not in PLANTS:
            raise ValueError(f"[robot] unknown plant '{r['plant']}': choose one of {', '.join(PLANTS)}")
        extra = sorted(set(r) - {"plant", "start"})
        if extra:
            raise ValueError(f"[robot] '{extra[0]}' goes with file, not with a built-in plant")
        if "start" not in r:
            return {"plant": r["plant"]}
        start = r["start"]  # the plant's start posture in place of its default: "zero", or {joint = value}
        if start != "zero" and not isinstance(start, dict):
            raise ValueError("[robot] start of a built-in plant must be \"zero\" or a table {joint = value}")
        return {"plant": r["plant"], "start": "zero" if start == "zero" else
                {k: _number(v, f"[robot] start.{k}") for k, v in start.items()}}
    from plants.model_file import default_srdf, resolve_model_file

    packages = {str(k): str((base / v).resolve()) for k, v in (r.get("packages") or {}).items()}
    path = resolve_model_file(str(r["file"]), base, packages)
    pose = r.get("weld_pose", [])
    if pose and (r.get("weld") is None or len(_vector(pose, "[robot] weld_pose")) != 6):
        raise ValueError("[robot] weld_pose is [x, y, z, roll, pitch, yaw] (m, rad) of the weld frame")
    out: dict[str, Any] = {"file": str(path), "packages": packages, "weld": r.get("weld"),
                           "weld_pose": [float(v) for v in pose],
                           "sha256": hashlib.sha256(path.read_bytes()).hexdigest()[:16]}
    for key in ("locked", "limits", "packages"):
        if key in r and not isinstance(r[key], dict):
            raise ValueError(f"[robot] {key} must be a table")
    out["locked"] = {k: _number(v, f"[robot] locked.{k}") for k, v in (r.get("locked") or {}).items()}
    start = r.get("start", {})
    if isinstance(start, str):
        out["start"] = start
        srdf = r.get("srdf")
        srdf_path = (base / srdf).resolve() if srdf else default_srdf(path)
        out["srdf"] = None if srdf_path is None else str(srdf_path)
        if srdf and not srdf_path.is_file():
            raise ValueError(f"[robot] srdf not found: {srdf_path}")
    elif isinstance(start, dict):
        out["start"] = {k: _number(v, f"[robot] start.{k}") for k, v in start.items()}
        out["srdf"] = None
    else:
        raise ValueError("[robot] start must be an SRDF posture name or a table {joint = value}")
    arm = r.get("armature", 0.0)
    if isinstance(arm, dict):
        out["armature"] = {k: _nonneg(v, f"[robot] armature.{k}") for k, v in arm.items()}
    else:
        out["armature"] = _nonneg(arm, "[robot] armature")
    limits = {}
    for j, lim in (r.get("limits") or {}).items():
        if not isinstance(lim, dict):
            raise ValueError(f"[robot] limits.{j} must be a table {{lower, upper, effort}}")
        _refuse_unknown(lim, {"lower", "upper", "effort"}, f"[robot] limits.{j}")
        limits[j] = {k: _number(v, f"[robot] limits.{j}.{k}") for k, v in lim.items()}
    out["limits"] = limits
    from plants.model_file import ModelError, facts_from

    facts = {k: r[k] for k in ROBOT_FACTS if k in r}
    try:
        facts_from(facts)  # checked here: one line naming the key
    except ModelError as e:
        raise ValueError(f"[robot] {e}") from None
    out.update(facts)
    if "true" in r:
        out["true"] = _true_robot(r["true"])
    return out


def _true_robot(t) -> dict:
    """``[robot.true]``: ``payload = {frame, mass (kg), com (3, m, in the frame)}``, ``mass_scale`` (> 0,
    every link's mass and inertia) and ``friction`` (N m s/rad, viscous, every planning joint), as
    the flat table :class:`plants.model_file.RobotSpec` stores (unset changes left out)."""
    if not isinstance(t, dict):
        raise ValueError("[robot.true] must be a table {payload, mass_scale, friction}")
    _refuse_unknown(t, TRUE_KEYS, "[robot.true]")
    out: dict[str, Any] = {}
    if "payload" in t:
        p = t["payload"]
        if not isinstance(p, dict):
            raise ValueError("[robot.true] payload must be a table {frame, mass, com}")
        _refuse_unknown(p, PAYLOAD_KEYS, "[robot.true] payload")
        if not isinstance(p.get("frame"), str) or "mass" not in p:
            raise ValueError("[robot.true] payload needs a frame (a name) and a mass (kg)")
        out.update(payload_frame=p["frame"], payload_mass=_nonneg(p["mass"], "[robot.true] payload mass"),
                   payload_com=_vector(p.get("com", [0.0, 0.0, 0.0]), "[robot.true] payload com", 3))
    if "mass_scale" in t:
        scale = _number(t["mass_scale"], "[robot.true] mass_scale")
        if not 0 < scale <= 100:
            raise ValueError(f"[robot.true] mass_scale must be in (0, 100], got {scale!r}")
        out["mass_scale"] = scale
    if "friction" in t:
        out["friction"] = _nonneg(t["friction"], "[robot.true] friction")
    return out


def _number(v, what: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"{what} must be a finite number, got {v!r}")
    return float(v)


def _nonneg(v, what: str) -> float:
    x = _number(v, what)
    if x < 0:
        raise ValueError(f"{what} must be >= 0, got {v!r}")
    return x


def _vector(v, what: str, n: int | None = None) -> list:
    a = np.asarray(v, dtype=float) if isinstance(v, list) else None
    if a is None or a.ndim != 1 or not np.all(np.isfinite(a)):
        raise ValueError(f"{what} must be a list of numbers, got {v!r}")
    if n is not None and a.size != n:
        raise ValueError(f"{what} has {a.size} values, expected {n}")
    return a.tolist()


def _times(v, T: int, name: str):
    if v is None:
        raise ValueError(f"[costs.{name}] needs times: a list of steps in [0, {T}], or one of {', '.join(TIMES)}")
    if isinstance(v, dict):
        _refuse_unknown(v, {"from", "to"}, f"[costs.{name}] times")
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


def _term(name: str, t: dict, T: int) -> dict:
    kind = t.get("type")
    if kind not in TERM_KEYS:
        raise ValueError(f"[costs.{name}] unknown type {kind!r}: choose one of {', '.join(TERM_KEYS)}")
    _refuse_unknown(t, TERM_KEYS[kind], f"[costs.{name}] ({kind})")
    if kind == "collision":
        return _collision(name, t, T)
    if "weight" not in t:
        raise ValueError(f"[costs.{name}] needs a weight")
    out = dict(t)
    if kind == "control" and isinstance(t["weight"], list):  # per-joint weights
        out["weight"] = [_nonneg(w, f"[costs.{name}] weight") for w in t["weight"]]
        if not out["weight"]:
            raise ValueError(f"[costs.{name}] weight must be a number or one number per joint")
    else:
        out["weight"] = _nonneg(t["weight"], f"[costs.{name}] weight")
    if kind == "control" and isinstance(t.get("target"), str) and t["target"] != "gravity":
        raise ValueError(f"[costs.{name}] target must be {{n}} numbers or \"gravity\" (the torque that holds the "
                         f"robot still), got {t['target']!r}")
    if "times" in TERM_KEYS[kind]:
        out["times"] = _times(t.get("times"), T, name)
    for key in ("frame", "in_frame", "angle", "relative", "map"):
        if key in t and not isinstance(t[key], str):
            raise ValueError(f"[costs.{name}] {key} must be a string")
    if kind in ("frame_position", "frame_orientation", "frame_placement") and "frame" not in t:
        raise ValueError(f"[costs.{name}] needs a frame")
    if "relative" in t and t["relative"] != "start":
        raise ValueError(f"[costs.{name}] relative must be \"start\"")
    if "angle" in t and t["angle"] not in ANGLES:
        raise ValueError(f"[costs.{name}] unknown angle '{t['angle']}': choose one of {', '.join(ANGLES)}")
    if kind == "frame_orientation" and "angle" not in t and ("rotation" in t) == ("rpy" in t):
        raise ValueError(f"[costs.{name}] needs rotation (3 x 3) or rpy (3), or angle = \"roll\" with a target")
    if kind == "frame_placement" and "position" not in t:
        raise ValueError(f"[costs.{name}] needs a position (3)")
    if "tol" in t:
        out["tol"] = _tol(t["tol"], name, kind)
    return out


def _scene(entries, base: Path, robot: dict) -> list[dict]:
    """``[[scene]]``: the canonical scene (``plants.scene.normalize_scene``; package URIs as the robot's)."""
    from plants.model_file import Packages
    from plants.scene import normalize_scene

    packages = Packages(dict(robot.get("packages") or {}), Path(robot["file"])) if "file" in robot else None
    return normalize_scene(entries, base, None if packages is None else lambda uri: packages.resolve(uri, base))


def _name_pairs(v, what: str) -> list[list[str]]:
    if not isinstance(v, list) or not all(isinstance(p, list) and len(p) == 2 and all(isinstance(x, str) for x in p)
                                          for p in v):
        raise ValueError(f"{what} must be a list of [name, name] pairs")
    return [list(p) for p in v]


def _collision(name: str, t: dict, T: int) -> dict:
    """A collision term (``type = "collision"``): ``pairs`` of ``[robot side, scene side]``, ``groups``
    (name -> links), ``self`` (the robot against itself), ``allow`` (pairs of links never checked, or
    ``"srdf"``: the robot's SRDF's ``<disable_collisions>``), ``margin`` (m, >= 0), ``hard`` (default true),
    ``max_distance`` (m, the query's culling distance, > margin), ``weight``, ``times``."""
    where = f"[costs.{name}]"
    if "margin" not in t:
        raise ValueError(f"{where} needs a margin (m): the smallest distance allowed")
    margin = _number(t["margin"], f"{where} margin")
    if margin < 0:
        raise ValueError(f"{where} margin must be >= 0 (m), got {margin:g}")
    hard = t.get("hard", True)
    if not isinstance(hard, bool):
        raise ValueError(f"{where} hard must be true or false")
    if not hard and "weight" not in t:
        raise ValueError(f"{where} needs a weight (a soft collision term)")
    from planning.costs import HARD_COLLISION_WEIGHT

    out: dict[str, Any] = {"type": "collision", "margin": margin, "hard": hard,
                           "weight": _nonneg(t.get("weight", HARD_COLLISION_WEIGHT), f"{where} weight"),
                           "times": _times(t.get("times", "all"), T, name),
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
    dmax = _number(t.get("max_distance", margin + CULL), f"{where} max_distance")
    if not dmax > margin:
        raise ValueError(f"{where} max_distance must be > margin ({margin:g} m), got {dmax:g}")
    out["max_distance"] = dmax
    if "map" in t:
        if not isinstance(t["map"], str):
            raise ValueError(f"{where} map must be a string")
        out["map"] = t["map"]
    return out


def _tol(v, name: str, kind: str):
    """A term's own tolerance of "task achieved": a number > 0 in its unit (m, rad); a frame placement's
    a number (both parts) or ``[m, rad]``."""
    vals = v if isinstance(v, list) and kind == "frame_placement" else [v]
    if len(vals) not in (1, 2) or any(isinstance(x, bool) or not isinstance(x, (int, float)) or not 0 < x < math.inf
                                      for x in vals):
        raise ValueError(f"[costs.{name}] tol must be a number > 0 (m or rad"
                         + (", or [m, rad] for a frame placement" if kind == "frame_placement" else "") + f"), got {v!r}")
    return [float(x) for x in vals] if isinstance(v, list) else float(v)


# ------------------------------------------------------------------ building
def _steps(times, T: int):
    if times == "last":
        return [T]
    if times == "all":
        return range(1, T + 1)
    if times == "running":
        return range(0, T)
    if times == "every":
        return range(0, T + 1)
    if isinstance(times, dict):
        return range(times["from"], times["to"] + 1)
    return list(times)


def _scale(convention: str, times, T: int, dt: float) -> list[tuple[Any, float]]:
    """(steps, weight factor) pieces: crocoddyl's running nodes cost ``dt/2``, its terminal one ``1/2``."""
    steps = _steps(times, T)
    if convention == "raico":
        return [(steps, 1.0)]
    steps = list(steps)
    running = [s for s in steps if s < T]
    pieces = []
    if running:
        pieces.append((range(running[0], running[-1] + 1) if len(running) == running[-1] - running[0] + 1
                       else running, 0.5 * dt))
    if T in steps:
        pieces.append(([T], 0.5))
    return pieces


def _rotation(t: dict, name: str, robot=None, q0=None) -> np.ndarray:
    if t.get("rotation") == "start":  # the frame's orientation at the start posture
        return robot.plant.GetFrameByName(t["frame"]).CalcPoseInWorld(robot.set_state(q0)).rotation().matrix()
    if "rotation" in t:
        R = np.asarray(t["rotation"], dtype=float)
        if R.shape != (3, 3) or not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ValueError(f"[costs.{name}] rotation must be a 3 x 3 rotation matrix")
        return R
    if "rpy" in t:
        from plants.model_file import rpy_matrix

        return rpy_matrix(_vector(t["rpy"], f"[costs.{name}] rpy", 3))
    return np.eye(3)


def resolve_frame(robot, frame: str, name: str) -> str:
    """The frame a term names: a frame of the plant, or a joint's name for the frame of its child
    link (Pinocchio's joint frames, which crocoddyl's examples name)."""
    plant = robot.plant
    if plant.HasFrameNamed(frame):
        return frame
    if plant.HasJointNamed(frame):
        return plant.GetJointByName(frame).child_body().body_frame().name()
    from plants.model_file import closest_names, frame_names

    raise ValueError(f"[costs.{name}] frame '{frame}' is not in the robot: closest "
                     f"{closest_names(frame, frame_names(plant))}")


def build_terms(problem: ProblemFile, robot, q0: np.ndarray, T: int) -> list:
    """The term descriptions (:mod:`planning.objective`) of ``problem`` at start posture ``q0``."""
    doc = problem.doc["costs"]
    convention, dt = doc["convention"], problem.dt
    out = []
    for name, t in doc["terms"].items():
        kind = t["type"]
        if kind == "control":
            out.append(_control(name, t, robot, 0.5 * dt if convention == "crocoddyl" else 1.0))
            continue
        if kind == "control_limit":
            w = t["weight"] * (0.5 * dt if convention == "crocoddyl" else 1.0)
            effort, n_u = robot.effort[robot.actuated], len(robot.actuated)  # an underactuated robot's motors
            lo = _vector(t["lower"], f"[costs.{name}] lower", n_u) if "lower" in t else (-effort).tolist()
            hi = _vector(t["upper"], f"[costs.{name}] upper", n_u) if "upper" in t else effort.tolist()
            out.append(ob.control_limit(lo, hi, w, name))
            continue
        if kind == "collision":
            pieces = _scale(convention, t["times"], T, dt)
            for k, (steps, factor) in enumerate(pieces):
                suffix = "" if len(pieces) == 1 else ("_running" if k == 0 and len(pieces) == 2 else "_terminal")
                out.append(_collision_term(f"{name}{suffix}", t, problem, robot, steps, t["weight"] * factor))
            continue
        pieces = _scale(convention, t["times"], T, dt)
        for k, (steps, factor) in enumerate(pieces):
            suffix = "" if len(pieces) == 1 else ("_running" if k == 0 and len(pieces) == 2 else "_terminal")
            out.append(_state_term(f"{name}{suffix}", t, robot, q0, steps, t["weight"] * factor))
    return out


def _collision_term(name: str, t: dict, problem: ProblemFile, robot, steps, weight: float) -> dict:
    """A collision term's description: its geometry pairs resolved on the robot's collision world
    (``plants.scene.resolve_pairs``; unknown links, groups and objects refused)."""
    from plants.scene import resolve_pairs, srdf_allowed

    scene = problem.doc.get("scene", [])
    world = _collision_world(robot.spec, scene)
    allow = t["allow"]
    if allow == "srdf":
        srdf = problem.doc["robot"].get("srdf")
        if srdf is None:
            from plants.model_file import default_srdf

            found = default_srdf(Path(problem.doc["robot"]["file"]))
            srdf = None if found is None else str(found)
        if srdf is None:
            raise ValueError(f"[costs.{name}] allow = \"srdf\": the robot has no SRDF (give srdf in [robot])")
        allow = srdf_allowed(srdf)
    groups = t["groups"]
    for g, links in groups.items():
        for link in links:
            if link not in groups and link not in world.robot_links() and link != "robot":
                from plants.model_file import closest_names

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
        from plants.scene import CollisionWorld

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
        w = np.asarray(_vector(w, f"[costs.{name}] weight", len(robot.actuated)))
        top = float(w.max())
        precision, w = (w / top if top > 0 else np.ones_like(w)).tolist(), top
    d = ob.control(w * factor, name)
    if t.get("target") == "gravity":
        d.update(target="gravity", controls="torque")
    elif "target" in t:
        d["target"] = _vector(t["target"], f"[costs.{name}] target", len(robot.actuated))
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


MAP_NAMES = {"com": "cog", "posture": "joints", "joint_limit": "joints"}


def _map_name(t: dict, name: str) -> str:
    """The task map's name (``map``): terms on maps of one name share a plot and a path in the
    recordings; by default a frame's name, ``cog``, ``joints``, or the term's own name."""
    if "map" in t:
        return t["map"]
    if t["type"] == "frame_position":
        return t["frame"]
    return MAP_NAMES.get(t["type"], name)


def _state_term(name: str, t: dict, robot, q0: np.ndarray, steps, weight: float) -> dict:
    from plants.taskmaps import CenterOfMass, FramePoints

    kind = t["type"]
    mname = _map_name(t, name)
    precision = t.get("precision")
    tol = t.get("tol")
    if kind in ("frame_position", "frame_orientation", "frame_placement"):
        t = {**t, "frame": resolve_frame(robot, t["frame"], name)}
    if kind == "frame_position":
        axes = tuple(t.get("axes", (0, 1, 2)))
        if not axes or any(a not in (0, 1, 2) for a in axes):
            raise ValueError(f"[costs.{name}] axes must be a list of 0, 1, 2")
        points = t.get("points")
        if "in_frame" in t:
            p = np.asarray(_vector(t.get("target"), f"[costs.{name}] target", 3))
            X = robot.plant.GetFrameByName(resolve_frame(robot, t["in_frame"], name)).CalcPoseInWorld(robot.set_state(q0))
            target = (X.rotation().matrix() @ p + X.translation())[list(axes)]
        else:
            at_start = FramePoints(robot, t["frame"], points=points).value(q0)
            at_start = at_start.reshape(-1, 3)[:, list(axes)].reshape(-1) if points is not None \
                else at_start[list(axes)]
            target = _target(t, name, at_start)
        m = ob.frame_points(t["frame"], mname, axes=axes, points=points)
        return ob.via(name, m, target, steps, weight, precision, tol)
    if kind == "frame_orientation":
        if "angle" in t:
            return ob.via(name, ob.roll(t["frame"], t.get("map", "roll")), [_number(t.get("target"), f"[costs.{name}] target")],
                          steps, weight, precision, tol)
        return ob.via(name, ob.frame_rotation(t["frame"], _rotation(t, name, robot, q0), mname), np.zeros(3), steps,
                      weight, precision, tol)
    if kind == "frame_placement":
        position = _vector(t["position"], f"[costs.{name}] position", 3)
        return ob.via(name, ob.frame_placement(t["frame"], _rotation(t, name, robot, q0), position, mname), np.zeros(6), steps,
                      weight, precision, tol)
    if kind == "com":
        axes = tuple(t.get("axes", (0, 1, 2)))
        at_start = CenterOfMass(robot).value(q0)[list(axes)]
        return ob.via(name, ob.cog(axes, mname), _target(t, name, at_start), steps, weight, precision, tol)
    if kind == "posture":
        idx = _joint_indices(robot, t.get("joints"), name)
        return ob.via(name, ob.joints(mname, idx), _target(t, name, q0[idx]), steps, weight, precision, tol)
    if kind == "state":
        if isinstance(precision, dict):  # {q = a, v = b}: one weight for the positions, one for the velocities
            _refuse_unknown(precision, {"q", "v"}, f"[costs.{name}] precision")
            precision = [_nonneg(precision.get("q", 1.0), f"[costs.{name}] precision.q")] * robot.n_q + \
                [_nonneg(precision.get("v", 1.0), f"[costs.{name}] precision.v")] * robot.n_q
        x0 = np.concatenate([q0, np.zeros(robot.n_q)])
        target = x0 if t.get("target", "start") == "start" else \
            np.asarray(_vector(t["target"], f"[costs.{name}] target", 2 * robot.n_q))
        return ob.state(name, target, steps, weight, precision)
    if kind == "joint_limit":
        idx = _joint_indices(robot, t.get("joints"), name)
        lo = np.asarray(_vector(t["lower"], f"[costs.{name}] lower", len(idx))) if "lower" in t else robot.lower[idx]
        hi = np.asarray(_vector(t["upper"], f"[costs.{name}] upper", len(idx))) if "upper" in t else robot.upper[idx]
        keep = np.isfinite(lo) | np.isfinite(hi)
        A = np.vstack([np.eye(len(idx)), -np.eye(len(idx))])
        b = np.concatenate([np.where(np.isfinite(hi), hi, 1e9), np.where(np.isfinite(lo), -lo, 1e9)])
        rows = np.concatenate([keep, keep])
        return ob.inequality(name, ob.joints(mname, idx), A[rows], b[rows], steps, weight)
    raise ValueError(f"[costs.{name}] unknown type {kind!r}")


def _joint_indices(robot, joints, name: str) -> list[int]:
    if joints is None:
        return list(range(robot.n_q))
    if not isinstance(joints, list) or not all(isinstance(j, str) for j in joints):
        raise ValueError(f"[costs.{name}] joints must be a list of joint names")
    from plants.model_file import closest_names

    out = []
    for j in joints:
        if j not in robot.joint_names:
            raise ValueError(f"[costs.{name}] joint '{j}' is not a planning joint: closest "
                             f"{closest_names(j, robot.joint_names)}")
        out.append(robot.joint_names.index(j))
    return out


def with_horizon(problem: ProblemFile, T: int) -> ProblemFile:
    """``problem`` at horizon ``T`` steps (same ``dt``): listed steps and ranges scaled by ``T / T0``
    (rounded; ``last``, ``all``, ``running`` and ``every`` follow the horizon). For sweeps over the
    horizon (``bench/scaling.py``)."""
    import copy

    doc = copy.deepcopy(problem.doc)
    T0 = int(doc["horizon"]["T"])

    def scale(step: int) -> int:
        return min(T, round(step * T / T0))

    for term in doc["costs"]["terms"].values():
        times = term.get("times")
        if isinstance(times, list):
            term["times"] = sorted({scale(t) for t in times})
        elif isinstance(times, dict):
            term["times"] = {"from": scale(times["from"]), "to": scale(times["to"])}
    doc["horizon"]["T"] = int(T)
    return ProblemFile(doc)


def shipped(plant: str, task: str) -> Path:
    return SHIPPED / f"{plant}_{task}.toml"
