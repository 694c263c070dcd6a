"""Problem files: a robot, a horizon, dynamics and named cost terms, written in TOML.

A problem file states a planning problem the way the field does (crocoddyl's action models,
EXOTica's task maps): a robot (a built-in plant, or a model file, :mod:`raico.plants.model_file`), the
horizon ``T`` steps of ``dt`` seconds, the dynamics model and its integrator, and cost terms, each a
task map with a target, a weight and the steps it applies at. Every key, its meaning and an example:
docs/problem-files.md (its key tables are generated from the sets here, from the robot's facts
``raico.plants.model_file.FACTS`` and from the cost kinds ``raico.planning.term_kinds.COST_KINDS``).

:func:`read_problem` checks a file and gives its canonical content (:class:`ProblemFile`, the cache
key's part); :func:`build_terms` gives its term descriptions (:mod:`raico.planning.objective`) on a robot at
the start posture. Each cost term goes through its row of the cost-kind table: its keys, its parser and
its describer (``raico.planning.problem_terms``). Unknown keys, names, shapes, negative weights and steps past
``T`` are refused (``ValueError``, one line with the valid choices).
"""

from __future__ import annotations

import hashlib
import json
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from raico.planning import problem_terms
from raico.planning.problem_terms import TermContext, check_tol, nonneg, number, refuse_unknown, vector
from raico.planning.term_kinds import COST_KINDS, cost_kind
from raico.plants.model_file import FACTS
from raico.plants.scene import COMMON_KEYS as SCENE_COMMON
from raico.plants.scene import SHAPES

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "problems"
TOP_KEYS = {"name", "description", "robot", "horizon", "dynamics", "costs", "achieved", "scene"}
ACHIEVED_KEYS = {"joint", "angle", "tol", "velocity_tol"}
# [robot]: the model file and how it is mounted, then the robot's facts (raico.plants.model_file.FACTS)
ROBOT_KEYS = {"plant", "file", "packages", "weld", "weld_pose", "locked", "start", "srdf", "armature", "limits",
              "true"} | set(FACTS)
TRUE_KEYS = {"payload", "mass_scale", "friction"}  # [robot.true]: the executed robot's differences from its file
PAYLOAD_KEYS = {"frame", "mass", "com"}
HORIZON_KEYS = {"T", "dt"}
DYNAMICS_KEYS = {"model", "integrator", "substeps"}
# dynamics model -> integrator -> raico's dynamics name (raico.plants.dynamics_registry)
INTEGRATORS = {"pseudo": {"backward-euler": "pseudo", "euler": "pseudo-euler", "heun": "pseudo-heun"},
               "analytic": {"semi-implicit-euler": "analytic"}}
CONVENTIONS = ("raico", "crocoddyl")
SCENE_KEYS = {kind: SCENE_COMMON | keys for kind, keys in SHAPES.items()}   # [[scene]] by type (raico.plants.scene)


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
        """Model steps per control step of ``dt`` (``raico.plants.dynamics.SubstepDynamics``; 1: one)."""
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
        """The :class:`raico.plants.model_file.RobotSpec` of a model-file robot, the planner's model (None for a
        built-in plant)."""
        if self.plant is not None:
            return None
        from raico.plants.model_file import RobotSpec

        return RobotSpec.from_dict(self.doc["robot"]).planning

    def true_spec(self):
        """The spec of the robot that is babbled on and executed: the model file's with ``[robot.true]``'s
        changes, or None when the problem states none (then the file's robot is the true one)."""
        if self.plant is not None or not self.doc["robot"].get("true"):
            return None
        from raico.plants.model_file import RobotSpec

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
    refuse_unknown(raw, TOP_KEYS, "problem file")
    for key in ("robot", "horizon", "costs"):
        if not isinstance(raw.get(key), dict):
            raise ValueError(f"problem file: missing table [{key}]")
    doc: dict[str, Any] = {"name": str(raw.get("name", default_name)),
                           "description": str(raw.get("description", ""))}
    doc["robot"] = _robot(raw["robot"], base)
    if "scene" in raw:
        doc["scene"] = _scene(raw["scene"], base, doc["robot"])
    if "achieved" in raw:
        doc["achieved"] = read_achieved(raw["achieved"])
    h = raw["horizon"]
    refuse_unknown(h, HORIZON_KEYS, "[horizon]")
    T, dt = h.get("T"), h.get("dt")
    if not isinstance(T, int) or not 1 <= T <= 100000:
        raise ValueError(f"[horizon] T must be an integer in [1, 100000], got {T!r}")
    if not isinstance(dt, (int, float)) or not 0 < dt <= 1.0:
        raise ValueError(f"[horizon] dt must be in (0, 1] s, got {dt!r}")
    doc["horizon"] = {"T": T, "dt": float(dt)}
    d = raw.get("dynamics", {})
    refuse_unknown(d, DYNAMICS_KEYS, "[dynamics]")
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
        kind = cost_kind(term.get("type"))
        if kind is not None and kind.geometry and "plant" in doc["robot"]:
            raise ValueError(f"[costs.{name}] {kind.type} terms need a robot from a model file (file), "
                             f"not the built-in plant '{doc['robot']['plant']}'")
    doc["costs"] = {"convention": convention, "terms": terms}
    return doc


def read_achieved(a) -> dict:
    """``[achieved]``: how an execution of the task is judged achieved, where the terms' own errors do not say it:
    joint ``joint`` ends within ``tol`` (rad) of ``angle`` (rad), the difference wrapped to (-pi, pi], and with a
    speed within ``velocity_tol`` (rad/s) where it is stated."""
    if not isinstance(a, dict):
        raise ValueError("[achieved] must be a table {joint, angle, tol}")
    refuse_unknown(a, ACHIEVED_KEYS, "[achieved]")
    if not isinstance(a.get("joint"), str) or "angle" not in a or "tol" not in a:
        raise ValueError("[achieved] needs joint (a name), angle (rad) and tol (rad)")
    tol = number(a["tol"], "[achieved] tol")
    if tol <= 0:
        raise ValueError(f"[achieved] tol must be > 0 (rad), got {tol}")
    out = {"joint": a["joint"], "angle": number(a["angle"], "[achieved] angle"), "tol": tol}
    if "velocity_tol" in a:
        vtol = number(a["velocity_tol"], "[achieved] velocity_tol")
        if vtol <= 0:
            raise ValueError(f"[achieved] velocity_tol must be > 0 (rad/s), got {vtol}")
        out["velocity_tol"] = vtol
    return out


def _robot(r: dict, base: Path) -> dict:
    refuse_unknown(r, ROBOT_KEYS, "[robot]")
    if ("plant" in r) == ("file" in r):
        raise ValueError("[robot]: give either plant (a built-in: pendulum, cartpole, arm5, biorob, nao) or file (a model file)")
    if "plant" in r:
        from raico.plants.robots import PLANTS

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
                {k: number(v, f"[robot] start.{k}") for k, v in start.items()}}
    from raico.plants.model_file import default_srdf, resolve_model_file

    packages = {str(k): str((base / v).resolve()) for k, v in (r.get("packages") or {}).items()}
    path = resolve_model_file(str(r["file"]), base, packages)
    pose = r.get("weld_pose", [])
    if pose and (r.get("weld") is None or len(vector(pose, "[robot] weld_pose")) != 6):
        raise ValueError("[robot] weld_pose is [x, y, z, roll, pitch, yaw] (m, rad) of the weld frame")
    out: dict[str, Any] = {"file": str(path), "packages": packages, "weld": r.get("weld"),
                           "weld_pose": [float(v) for v in pose],
                           "sha256": hashlib.sha256(path.read_bytes()).hexdigest()[:16]}
    for key in ("locked", "limits", "packages"):
        if key in r and not isinstance(r[key], dict):
            raise ValueError(f"[robot] {key} must be a table")
    out["locked"] = {k: number(v, f"[robot] locked.{k}") for k, v in (r.get("locked") or {}).items()}
    start = r.get("start", {})
    if isinstance(start, str):
        out["start"] = start
        srdf = r.get("srdf")
        srdf_path = (base / srdf).resolve() if srdf else default_srdf(path)
        out["srdf"] = None if srdf_path is None else str(srdf_path)
        if srdf and not srdf_path.is_file():
            raise ValueError(f"[robot] srdf not found: {srdf_path}")
    elif isinstance(start, dict):
        out["start"] = {k: number(v, f"[robot] start.{k}") for k, v in start.items()}
        out["srdf"] = None
    else:
        raise ValueError("[robot] start must be an SRDF posture name or a table {joint = value}")
    arm = r.get("armature", 0.0)
    if isinstance(arm, dict):
        out["armature"] = {k: nonneg(v, f"[robot] armature.{k}") for k, v in arm.items()}
    else:
        out["armature"] = nonneg(arm, "[robot] armature")
    limits = {}
    for j, lim in (r.get("limits") or {}).items():
        if not isinstance(lim, dict):
            raise ValueError(f"[robot] limits.{j} must be a table {{lower, upper, effort}}")
        refuse_unknown(lim, {"lower", "upper", "effort"}, f"[robot] limits.{j}")
        limits[j] = {k: number(v, f"[robot] limits.{j}.{k}") for k, v in lim.items()}
    out["limits"] = limits
    from raico.plants.model_file import ModelError, facts_from

    facts = {k: r[k] for k in FACTS if k in r}
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
    the flat table :class:`raico.plants.model_file.RobotSpec` stores (unset changes left out)."""
    if not isinstance(t, dict):
        raise ValueError("[robot.true] must be a table {payload, mass_scale, friction}")
    refuse_unknown(t, TRUE_KEYS, "[robot.true]")
    out: dict[str, Any] = {}
    if "payload" in t:
        p = t["payload"]
        if not isinstance(p, dict):
            raise ValueError("[robot.true] payload must be a table {frame, mass, com}")
        refuse_unknown(p, PAYLOAD_KEYS, "[robot.true] payload")
        if not isinstance(p.get("frame"), str) or "mass" not in p:
            raise ValueError("[robot.true] payload needs a frame (a name) and a mass (kg)")
        out.update(payload_frame=p["frame"], payload_mass=nonneg(p["mass"], "[robot.true] payload mass"),
                   payload_com=vector(p.get("com", [0.0, 0.0, 0.0]), "[robot.true] payload com", 3))
    if "mass_scale" in t:
        scale = number(t["mass_scale"], "[robot.true] mass_scale")
        if not 0 < scale <= 100:
            raise ValueError(f"[robot.true] mass_scale must be in (0, 100], got {scale!r}")
        out["mass_scale"] = scale
    if "friction" in t:
        out["friction"] = nonneg(t["friction"], "[robot.true] friction")
    return out


def _term(name: str, t: dict, T: int) -> dict:
    """A cost term checked by its row of the cost-kind table (its keys, its parser, its tolerances)."""
    row = cost_kind(t.get("type"))
    if row is None:
        raise ValueError(f"[costs.{name}] unknown type {t.get('type')!r}: choose one of "
                         f"{', '.join(k.type for k in COST_KINDS)}")
    refuse_unknown(t, row.keys, f"[costs.{name}] ({row.type})")
    out = getattr(problem_terms, row.check)(name, t, T)
    if "tol" in t:
        out["tol"] = check_tol(t["tol"], name, row.tolerance_parts)
    return out


def _scene(entries, base: Path, robot: dict) -> list[dict]:
    """``[[scene]]``: the canonical scene (``raico.plants.scene.normalize_scene``; package URIs as the robot's)."""
    from raico.plants.model_file import Packages
    from raico.plants.scene import normalize_scene

    packages = Packages(dict(robot.get("packages") or {}), Path(robot["file"])) if "file" in robot else None
    return normalize_scene(entries, base, None if packages is None else lambda uri: packages.resolve(uri, base))


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


def build_terms(problem: ProblemFile, robot, q0: np.ndarray, T: int) -> list:
    """The term descriptions (:mod:`raico.planning.objective`) of ``problem`` at start posture ``q0``: each
    term's describer (its row of the cost-kind table) once per piece of its steps (crocoddyl's convention
    splits running and terminal steps: ``NAME_running``, ``NAME_terminal``); a term on the controls once,
    its weight as a running cost's."""
    doc = problem.doc["costs"]
    convention, dt = doc["convention"], problem.dt
    ctx = TermContext(problem, robot, q0)
    out = []
    for name, t in doc["terms"].items():
        row = cost_kind(t["type"])
        describe = getattr(problem_terms, row.describe)
        if "times" not in row.keys:  # on the controls, every step
            out.append(describe(name, t, ctx, None, 0.5 * dt if convention == "crocoddyl" else 1.0))
            continue
        pieces = _scale(convention, t["times"], T, dt)
        for k, (steps, factor) in enumerate(pieces):
            suffix = "" if len(pieces) == 1 else ("_running" if k == 0 and len(pieces) == 2 else "_terminal")
            if "moving" in t:   # a moving target: one term per step, each with the target of its time
                out += [describe(f"{name}{suffix}_t{s}", _moved(t, s * dt), ctx, [s], factor) for s in steps]
            else:
                out.append(describe(f"{name}{suffix}", t, ctx, steps, factor))
    return out


def _moved(t: dict, time: float) -> dict:
    """A moving target's term (``moving``) at ``time`` (s): its ``target`` (zero where not given) plus
    the offset of :func:`raico.planning.problem_terms.moving_offset`."""
    base = np.zeros(3) if t.get("target") is None else np.asarray(t["target"], float)
    return {**t, "target": (base + problem_terms.moving_offset(t["moving"], time)).tolist()}


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
