"""A robot from its model file (URDF, SDF or MJCF): loaded into Drake, repaired, reported.

``load_model(spec)`` gives a :class:`raico.plants.robot.Robot` (the built-in plants load through it too,
``raico.plants.robots``): a finalized plant registered with a scene graph, its planning joints (every 1-DOF
joint that is not locked, in the plant's position order, so ``P`` is the identity unless joints are
coupled), limits and efforts from the file (overridable), a start posture, the robot's facts and a
short load report that says what the load changed.

The robot is stated by a :class:`RobotSpec` (the ``[robot]`` table of a problem file; its keys and what
they mean: docs/problem-files.md): where the file is (``file``, ``packages``), how it is mounted
(``weld``, ``weld_pose``, ``locked``), its ``start``, ``armature`` and ``limits``, how the executed robot
differs from the file (``true``: ``mass_scale``, a payload, ``friction``; :func:`true_spec`) and its
facts: what raico needs to know of a robot beyond its file (:data:`FACTS`, one row each; the defaults are
a fixed-base arm's; a floating robot's ``stand``: :mod:`raico.plants.stand`). A new fact is a field of :class:`RobotSpec` and a row of :data:`FACTS`.

Repairs (URDF; each one is a line of the report): ``package:///`` rewritten to ``package://``;
``<mimic>`` tags dropped; transmissions replaced by one actuator per planning joint with the file's
effort limit (0 or none: unlimited); ``<collision>`` elements dropped (collision terms read them again,
``raico.plants.scene``); a visual whose mesh file does not exist dropped; relative mesh paths made absolute;
duplicate top-level materials dropped; a robot without a name named after its file. Unsupported content
is one clear ``ModelError``: a floating joint inside the tree, a joint type the planning coordinates
cannot hold (ball, planar, universal), a kinematic loop.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import sysconfig
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from raico.plants.stand import Stand, StandError, missing_for_floating, stand_from

if TYPE_CHECKING:
    from raico.plants.robot import Robot

DRAKE_GRAVITY = 9.81  # m/s^2, Drake's default gravity
FORMATS = {".urdf": "urdf", ".sdf": "sdf", ".xml": "mjcf"}
ONE_DOF_JOINTS = ("revolute", "prismatic")  # Drake's names (a URDF "continuous" joint is a revolute one)


class ModelError(ValueError):
    """A model file that cannot be loaded as stated (one line: what, where, what to do)."""


@dataclass(frozen=True)
class RobotSpec:
    """A robot stated by its model file (see the module docstring). Paths are absolute."""

    file: str
    packages: tuple[tuple[str, str], ...] = ()
    weld: str | None = None
    weld_pose: tuple[float, ...] = ()  # (x, y, z, roll, pitch, yaw) of the welded frame in the world
    locked: tuple[tuple[str, float], ...] = ()
    start: str | tuple[tuple[str, float], ...] = ()
    srdf: str | None = None
    armature: float | tuple[tuple[str, float], ...] = 0.0
    limits: tuple[tuple[str, tuple[tuple[str, float], ...]], ...] = ()
    true: tuple[tuple[str, Any], ...] = ()  # the true robot's changes (module docstring); () for the file's
    # the robot's facts (module docstring, "Facts"); their defaults are a fixed-base arm's
    plant: str | None = None  # a built-in plant's name (raico/plants/models/NAME.toml); its robot is called so
    order: str = "tree"  # planning joints in Drake's tree order ("tree") or in the file's ("file")
    coupled: tuple[tuple[str, str], ...] = ()  # joint -> the planning joint it copies (one motor)
    end_effectors: tuple[tuple[str, str], ...] = ()  # label -> frame
    hands: tuple[str, ...] = ()  # frames drawn as hands in the recordings
    feet: tuple[str, ...] = ()  # soles, the stance (welded) one first
    sole: tuple[tuple[float, float], ...] = ()  # (k, 2) a sole's outline in its frame (m)
    execution: str = "discrete"  # EXECUTIONS
    time_step: float = 1e-3  # s, the execution's step (a discrete plant's; a continuous one's largest integrator step)
    learn: tuple[tuple[str, int], ...] = ()  # the learning loop's defaults {babble_points, stride}
    unactuated: tuple[str, ...] = ()  # planning joints without a motor (effort 0)
    gravity: float = DRAKE_GRAVITY  # m/s^2, along -z
    stand: Stand | None = None  # how a floating robot stands (raico.plants.stand)

    def to_dict(self) -> dict:
        """JSON form (stored with a plan; :meth:`from_dict` inverts it). Facts at their defaults are left
        out, so a model file's stored spec reads as before they existed."""
        extra: dict[str, Any] = {"true": {k: list(v) if isinstance(v, tuple) else v for k, v in self.true}} \
            if self.true else {}
        extra.update({key: fact.json(getattr(self, key)) for key, fact in FACTS.items()
                      if getattr(self, key) != fact_default(key)})
        return {**extra, "file": self.file, "packages": dict(self.packages), "weld": self.weld,
                "weld_pose": list(self.weld_pose), "locked": dict(self.locked),
                "start": self.start if isinstance(self.start, str) else dict(self.start), "srdf": self.srdf,
                "armature": self.armature if isinstance(self.armature, float) else dict(self.armature),
                "limits": {j: dict(v) for j, v in self.limits}}

    @classmethod
    def from_dict(cls, d: dict) -> RobotSpec:
        def items(m):
            return tuple(sorted((str(k), float(v)) for k, v in (m or {}).items()))

        start = d.get("start") or {}
        armature = d.get("armature", 0.0)
        return cls(file=str(d["file"]), packages=tuple(sorted((str(k), str(v)) for k, v in
                                                              (d.get("packages") or {}).items())),
                   weld=d.get("weld"), weld_pose=tuple(float(v) for v in (d.get("weld_pose") or ())),
                   locked=items(d.get("locked")),
                   start=start if isinstance(start, str) else items(start), srdf=d.get("srdf"),
                   armature=float(armature) if isinstance(armature, (int, float)) else items(armature),
                   limits=tuple(sorted((str(j), items(v)) for j, v in (d.get("limits") or {}).items())),
                   true=true_items(d.get("true")), **facts_from(d))

    @property
    def planning(self) -> RobotSpec:
        """The model file's robot (the planner's model): this spec without the true robot's changes."""
        return replace(self, true=())


EXECUTIONS = ("discrete", "continuous", "floating")
LEARN_KEYS = ("babble_points", "stride")


def _plain(v):
    """A fact's JSON form: a tuple as a list, anything else as it is."""
    return list(v) if isinstance(v, tuple) else v


def _pairs(key: str):
    def read(v):
        return tuple((str(a), str(b)) for a, b in _table(v, key).items())  # in the order given
    return read


def _name_list(key: str):
    def read(v):
        return tuple(str(x) for x in _list(v, key))
    return read


def _choice(key: str, choices: tuple[str, ...], what: str):
    def read(v):
        if v not in choices:
            raise ModelError(f"{key} '{v}': {what}")
        return str(v)
    return read


def _read_learn(v):
    t = _table(v, "learn")
    bad = sorted(set(t) - set(LEARN_KEYS))
    if bad or not all(isinstance(x, int) and x > 0 for x in t.values()):
        raise ModelError(f"learn: {{{', '.join(LEARN_KEYS)}}} as integers > 0, got {t}")
    return tuple(sorted((str(a), int(b)) for a, b in t.items()))


def _read_gravity(v):
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v <= 100:
        raise ModelError(f"gravity must be a number of m/s^2 in [0, 100], got {v}")
    return float(v)


def _read_sole(v):
    pts = np.asarray(_list(v, "sole"), float)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 3:
        raise ModelError(f"sole: a list of at least 3 [x, y] corners (m), got {v}")
    return tuple((float(x), float(y)) for x, y in pts)


def _read_time_step(v):
    if not isinstance(v, (int, float)) or not 1e-5 <= v <= 0.1:
        raise ModelError(f"time_step must be a number of seconds in [1e-5, 0.1], got {v}")
    return float(v)


@dataclass(frozen=True)
class Fact:
    """One row of :data:`FACTS`: a ``[robot]`` key, which is the :class:`RobotSpec` field of that name (its
    default there), ``read`` (its TOML/JSON value checked -> the field's value; ``ModelError`` naming the key)
    and ``json`` (the field's value -> its JSON form)."""

    key: str
    read: Callable[[Any], Any]
    json: Callable[[Any], Any] = _plain


# The robot's facts: the schema of [robot] beyond its file (raico/plants/models/NAME.toml, a problem file's [robot],
# a plan's stored spec). A new fact: a RobotSpec field (with its default) and a row here.
def _read_stand(v):
    try:
        return stand_from(v)
    except StandError as e:
        raise ModelError(str(e)) from None


FACTS: dict[str, Fact] = {f.key: f for f in (
    Fact("plant", str),
    Fact("order", _choice("order", ("tree", "file"), "choose tree (Drake's) or file")),
    Fact("coupled", _pairs("coupled"), dict),
    Fact("end_effectors", _pairs("end_effectors"), dict),
    Fact("hands", _name_list("hands")),
    Fact("feet", _name_list("feet")),
    Fact("sole", _read_sole, lambda v: [list(p) for p in v]),
    Fact("execution", _choice("execution", EXECUTIONS, f"choose one of {', '.join(EXECUTIONS)}")),
    Fact("time_step", _read_time_step),
    Fact("learn", _read_learn, dict),
    Fact("unactuated", _name_list("unactuated")),
    Fact("gravity", _read_gravity),
    Fact("stand", _read_stand, lambda v: v.to_json()),  # how a floating robot stands (raico.plants.stand)
)}


def fact_default(key: str):
    """The default of fact ``key``: its :class:`RobotSpec` field's (a fixed-base arm's)."""
    return RobotSpec.__dataclass_fields__[key].default


def facts_from(d: dict) -> dict:
    """The robot's facts of a spec's JSON or TOML form ``d`` as :class:`RobotSpec` fields (checked; absent:
    left out, so the defaults hold)."""
    return {key: fact.read(d[key]) for key, fact in FACTS.items() if d.get(key) is not None}


def _table(v, key: str) -> dict:
    if not isinstance(v, dict):
        raise ModelError(f"{key} must be a table")
    return v


def _list(v, key: str) -> list:
    if not isinstance(v, (list, tuple)):
        raise ModelError(f"{key} must be a list")
    return list(v)


TRUE_KEYS = ("friction", "mass_scale", "payload_com", "payload_frame", "payload_mass")
PAYLOAD_RADIUS = 0.03  # m, the true payload: a solid sphere of its mass (its inertia matters little)


def true_items(d: dict | None) -> tuple[tuple[str, object], ...]:
    """The hashable form of a true robot's changes ``{mass_scale, payload_mass, payload_frame,
    payload_com, friction}`` (lists as tuples, sorted by key)."""
    return tuple(sorted((str(k), tuple(float(x) for x in v) if isinstance(v, (list, tuple)) else v)
                        for k, v in (d or {}).items()))


def true_spec(spec: RobotSpec, true: dict | None) -> RobotSpec:
    """``spec`` with the true robot's changes ``true`` (None or empty: ``spec`` itself)."""
    return replace(spec, true=true_items(true)) if true else spec


# ------------------------------------------------------------------ packages
def example_robot_data() -> Path | None:
    """The installed example-robot-data share folder (``<site-packages>/cmeel.prefix/share/...``)."""
    for key in ("purelib", "platlib"):
        p = Path(sysconfig.get_paths()[key]) / "cmeel.prefix" / "share" / "example-robot-data"
        if p.is_dir():
            return p
    return None


def _package_xml_name(folder: Path) -> str | None:
    f = folder / "package.xml"
    if not f.is_file():
        return None
    try:
        node = ET.parse(f).getroot().find("name")
    except ET.ParseError:
        return None
    return None if node is None or node.text is None else node.text.strip()


class Packages:
    """``package://NAME/rest`` -> a file: the spec's map, example-robot-data, then the model
    file's parent folders (a folder named NAME, or one whose package.xml says NAME)."""

    def __init__(self, given: dict[str, str], model: Path):
        self.paths: dict[str, Path] = {k: Path(v) for k, v in given.items()}
        erd = example_robot_data()
        if erd is not None:
            for name in ("example-robot-data", "example_robot_data"):
                self.paths.setdefault(name, erd)
        self.model = model
        self.searched: dict[str, list[str]] = {}

    def folder(self, name: str) -> Path:
        if name in self.paths:
            return self.paths[name]
        tried = []
        for parent in [self.model.parent, *self.model.parents]:
            for cand in (parent, parent / name):
                tried.append(str(cand))
                if cand.is_dir() and (cand.name == name or _package_xml_name(cand) == name):
                    self.paths[name] = cand
                    return cand
        raise ModelError(f"package '{name}' cannot be resolved: not in the robot's packages "
                         f"({', '.join(sorted(self.paths)) or 'none given'}); searched {', '.join(tried[:6])}"
                         f"{' ...' if len(tried) > 6 else ''}; add it as packages.{name} = \"<folder>\"")

    def resolve(self, uri: str, base: Path) -> Path:
        """A mesh or model URI as a path (``package://``, ``file://``, relative to ``base``)."""
        if uri.startswith("package://"):
            rest = uri[len("package://"):].lstrip("/")
            name, _, sub = rest.partition("/")
            return self.folder(name) / sub
        if uri.startswith("file://"):
            return Path(uri[len("file://"):])
        p = Path(uri)
        return p if p.is_absolute() else base / p

    def used(self) -> dict[str, str]:
        return {k: str(v) for k, v in self.paths.items()}


def resolve_model_file(file: str, base: Path, packages: dict[str, str]) -> Path:
    """The model file's path (a ``package://`` URI through :class:`Packages`); missing: ``ModelError``."""
    pk = Packages(packages, base / "model")
    path = pk.resolve(file, base).resolve()
    if not path.is_file():
        raise ModelError(f"robot file not found: {path}")
    if path.suffix.lower() not in FORMATS:
        raise ModelError(f"robot file {path.name}: unknown format '{path.suffix}': choose one of "
                         f"{', '.join(FORMATS)} (URDF, SDF, MJCF)")
    return path


# ------------------------------------------------------------------ URDF repairs
def rpy_matrix(rpy) -> np.ndarray:
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _matrix_rpy(R: np.ndarray) -> tuple[float, float, float]:
    p = math.atan2(-R[2, 0], math.hypot(R[0, 0], R[1, 0]))
    return math.atan2(R[2, 1], R[2, 2]), p, math.atan2(R[1, 0], R[0, 0])


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def _floats(text: str | None, n: int, default: float = 0.0) -> np.ndarray:
    if not text:
        return np.full(n, default)
    return np.array([float(s) for s in text.split()], float)


def _lock_joint(joint: ET.Element, value: float) -> None:
    """A revolute/prismatic joint turned into a fixed one at ``value`` (its origin composed)."""
    kind = joint.get("type")
    origin = joint.find("origin")
    if origin is None:
        origin = ET.SubElement(joint, "origin")
    xyz, rpy = _floats(origin.get("xyz"), 3), _floats(origin.get("rpy"), 3)
    axis_el = joint.find("axis")
    axis = _floats(axis_el.get("xyz") if axis_el is not None else None, 3) if axis_el is not None \
        else np.array([1.0, 0.0, 0.0])
    R = rpy_matrix(rpy)
    if kind in ("revolute", "continuous"):
        R = R @ _axis_angle(axis, value)
    elif kind == "prismatic":
        xyz = xyz + R @ (axis / np.linalg.norm(axis) * value)
    origin.set("xyz", " ".join(repr(float(v)) for v in xyz))
    origin.set("rpy", " ".join(repr(float(v)) for v in _matrix_rpy(R)))
    joint.set("type", "fixed")
    for tag in ("axis", "limit", "dynamics", "mimic", "safety_controller", "calibration"):
        for el in joint.findall(tag):
            joint.remove(el)


def repair_urdf(text: str, path: Path, packages: Packages, locked: dict[str, float]) -> tuple[str, list[str]]:
    """The URDF as Drake can load it, and the report of what changed (see the module docstring)."""
    notes: list[str] = []
    n = text.count("package:///")
    if n:
        text = text.replace("package:///", "package://")
        notes.append(f"'package:///' rewritten to 'package://' ({n} URIs)")
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise ModelError(f"{path.name}: not valid XML: {e}") from None
    if root.tag != "robot":
        raise ModelError(f"{path.name}: a URDF's root element is <robot>, found <{root.tag}>")
    if not root.get("name"):
        root.set("name", path.stem)
        notes.append(f"the robot has no name: named '{path.stem}'")
    links = {link.get("name") for link in root.findall("link")}
    dangling = [j for j in root.findall("joint")
                if {(j.find("parent") if j.find("parent") is not None else ET.Element("x")).get("link"),
                    (j.find("child") if j.find("child") is not None else ET.Element("x")).get("link")} - links]
    for j in dangling:  # a joint to a link the file does not have
        root.remove(j)
    if dangling:
        notes.append(f"{len(dangling)} joints to links the file does not have dropped "
                     f"({_names([j.get('name') for j in dangling])})")
    joints = {j.get("name"): j for j in root.findall("joint")}
    mimics = [j.get("name") for j in joints.values() if j.find("mimic") is not None]
    for j in joints.values():
        for el in j.findall("mimic"):
            j.remove(el)
    if mimics:
        notes.append(f"<mimic> dropped on {len(mimics)} joints ({_names(mimics)}): they move independently")
    unknown = sorted(set(locked) - set(joints))
    if unknown:
        raise ModelError(f"locked joint '{unknown[0]}' is not in {path.name}: closest "
                         f"{closest_names(unknown[0], joints)}")
    for name, value in locked.items():
        if joints[name].get("type") not in ("revolute", "continuous", "prismatic"):
            raise ModelError(f"locked joint '{name}' is a {joints[name].get('type')} joint: only revolute, "
                             "continuous and prismatic joints can be locked")
        _lock_joint(joints[name], value)
    if locked:
        notes.append(f"{len(locked)} joints locked as welds ({_names([f'{k}={v:g}' for k, v in locked.items()])})")
    trans = root.findall("transmission")
    for t in trans:
        root.remove(t)
    if trans:
        notes.append(f"{len(trans)} transmissions replaced by one actuator per planning joint")
    ncol = 0
    for link in root.findall("link"):
        for c in link.findall("collision"):
            link.remove(c)
            ncol += 1
    if ncol:
        notes.append(f"{ncol} <collision> elements dropped from the dynamics (collision terms read them: raico.plants.scene)")
    missing, seen_mat, dup = [], set(), 0
    for m in root.findall("material"):
        name = m.get("name")
        if name in seen_mat:
            root.remove(m)
            dup += 1
        seen_mat.add(name)
    for m in root.findall("link/visual/material"):  # a second definition of a name becomes a reference
        name = m.get("name")
        if name in seen_mat and len(m):
            for child in list(m):
                m.remove(child)
            dup += 1
        if len(m):
            seen_mat.add(name)
    if dup:
        notes.append(f"{dup} repeated material definitions dropped (the first one kept)")
    defined = {m.get("name") for m in root.iter("material") if len(m)}
    undefined = 0
    for vis in root.findall("link/visual"):  # a reference to a material nothing defines: the default colour
        for m in vis.findall("material"):
            if not len(m) and m.get("name") not in defined:
                vis.remove(m)
                undefined += 1
    if undefined:
        notes.append(f"{undefined} references to undefined materials dropped (default colour)")
    for link in root.findall("link"):
        for vis in link.findall("visual"):
            mesh = vis.find("geometry/mesh")
            if mesh is None or mesh.get("filename") is None:
                continue
            uri = mesh.get("filename")
            f = packages.resolve(uri, path.parent)
            if not f.is_file():
                link.remove(vis)
                missing.append(uri)
            elif not uri.startswith("package://"):
                mesh.set("filename", str(f.resolve()))
    if missing:
        notes.append(f"{len(missing)} visuals dropped: mesh file missing ({_names(missing, 2)})")
    return ET.tostring(root, encoding="unicode"), notes


def _names(items: list[str], k: int = 3) -> str:
    return ", ".join(items[:k]) + (f" and {len(items) - k} more" if len(items) > k else "")


def closest_names(name: str, choices) -> str:
    import difflib

    near = difflib.get_close_matches(name, list(choices), n=3, cutoff=0.3)
    return ", ".join(near) if near else ", ".join(sorted(choices)[:5])


# ------------------------------------------------------------------ SRDF
def srdf_postures(srdf: Path) -> dict[str, dict[str, float]]:
    """The named postures (``<group_state>``) of an SRDF: name -> joint values."""
    try:
        root = ET.parse(srdf).getroot()
    except (OSError, ET.ParseError) as e:
        raise ModelError(f"SRDF {srdf}: cannot be read ({e})") from None
    out: dict[str, dict[str, float]] = {}
    for gs in root.findall("group_state"):
        vals = out.setdefault(gs.get("name"), {})
        for j in gs.findall("joint"):
            v = j.get("value")
            if v is not None and len(v.split()) == 1:
                vals[j.get("name")] = float(v)
    return out


def default_srdf(model: Path) -> Path | None:
    """``<pkg>/srdf/<stem>.srdf`` beside a ``<pkg>/{robots,urdf}/<stem>.urdf`` (example-robot-data's layout)."""
    for cand in (model.parent.parent / "srdf" / f"{model.stem}.srdf", model.with_suffix(".srdf")):
        if cand.is_file():
            return cand
    folder = model.parent.parent / "srdf"  # talos_reduced.urdf -> talos.srdf
    found = sorted(folder.glob("*.srdf")) if folder.is_dir() else []
    found = [f for f in found if model.stem.startswith(f.stem)]
    return max(found, key=lambda f: len(f.stem)) if found else None


# ------------------------------------------------------------------ loading
@dataclass
class Loaded:
    """A parsed, finalized model with its planning view and the load report."""

    robot: Robot
    report: list[str] = field(default_factory=list)


def spec_digest(spec: RobotSpec, text: str) -> str:
    """Identity of a loaded model: the repaired file's text and the spec (12 hex)."""
    doc = json.dumps({"text": text, "spec": spec.to_dict()}, sort_keys=True)
    return hashlib.sha256(doc.encode()).hexdigest()[:12]


def model_text(spec: RobotSpec) -> tuple[Path, str, str, list[str], Packages]:
    """The model file of ``spec`` as Drake reads it: ``(path, format, text, notes, packages)``, a URDF's text
    repaired (:func:`repair_urdf`) and ``[robot.true]``'s mass scale applied (``ModelError`` otherwise)."""
    path = Path(spec.file)
    if not path.is_file():
        raise ModelError(f"robot file not found: {path}")
    fmt = FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise ModelError(f"robot file {path.name}: unknown format '{path.suffix}': choose one of "
                         f"{', '.join(FORMATS)} (URDF, SDF, MJCF)")
    packages = Packages(dict(spec.packages), path)
    text = path.read_text(errors="replace")
    notes: list[str] = []
    if fmt == "urdf":
        text, notes = repair_urdf(text, path, packages, dict(spec.locked))
    elif spec.locked:
        raise ModelError(f"locked joints are supported for URDF files, not {fmt.upper()} ({path.name})")
    scale = dict(spec.true).get("mass_scale", 1.0)
    if scale != 1.0:
        if fmt != "urdf":
            raise ModelError(f"[robot.true] mass_scale is supported for URDF files, not {fmt.upper()} ({path.name})")
        text = scale_masses(text, float(scale))
        notes.append(f"true robot: every link's mass and inertia x {scale:g}")
    return path, fmt, text, notes, packages


def scale_masses(text: str, scale: float) -> str:
    """A URDF's text with every ``<inertial>``'s mass and inertia multiplied by ``scale`` (> 0)."""
    root = ET.fromstring(text)
    for inertial in root.iter("inertial"):
        mass = inertial.find("mass")
        if mass is not None and mass.get("value") is not None:
            mass.set("value", repr(float(mass.get("value")) * scale))
        inertia = inertial.find("inertia")
        if inertia is not None:
            for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"):
                if inertia.get(k) is not None:
                    inertia.set(k, repr(float(inertia.get(k)) * scale))
    return ET.tostring(root, encoding="unicode")


def _apply_true(plant, spec: RobotSpec, path: Path, planning: list) -> list[str]:
    """The true robot's payload (a solid sphere of radius PAYLOAD_RADIUS welded to its frame) and joint friction (viscous damping
    on every planning joint), before the plant is finalized; the report's lines."""
    from pydrake.math import RigidTransform
    from pydrake.multibody.tree import SpatialInertia

    true, notes = dict(spec.true), []
    mass = float(true.get("payload_mass", 0.0))
    if mass > 0:
        frame = str(true.get("payload_frame", ""))
        if not plant.HasFrameNamed(frame):
            raise ModelError(f"[robot.true] payload frame '{frame}' is not in {path.name}: closest "
                             f"{closest_names(frame, frame_names(plant))}")
        com = np.asarray(true.get("payload_com", (0.0, 0.0, 0.0)), float)
        parent = plant.GetFrameByName(frame)
        body = plant.AddRigidBody("raico_true_payload", parent.body().model_instance(),
                                  SpatialInertia.SolidSphereWithMass(mass, PAYLOAD_RADIUS))
        plant.WeldFrames(parent, body.body_frame(), RigidTransform(com))
        notes.append(f"true robot: a {mass:g} kg payload at '{frame}' ({', '.join(f'{v:g}' for v in com)} m)")
    friction = float(true.get("friction", 0.0))
    if friction > 0:
        for j in planning:
            j.set_default_damping(friction)
        notes.append(f"true robot: joint friction {friction:g} N m s/rad on every planning joint")
    return notes


def load_model(spec: RobotSpec, builder=None, time_step: float = 0.0, before_finalize=None) -> Robot:
    """A fresh :class:`~raico.plants.robots.Robot` from ``spec`` (its report in ``robot.load_report``);
    ``before_finalize(plant, text, path, packages)``, where given, adds to the plant before it is finalized
    (a scene's geometry, ``raico.plants.scene``)."""
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.multibody.tree import JointIndex
    from pydrake.systems.framework import DiagramBuilder

    from raico.plants.robot import Robot

    path, fmt, text, notes, packages = model_text(spec)
    missing = missing_for_floating(spec) if spec.execution == "floating" else []
    if missing:
        raise ModelError(f"{path.name}: execution = \"floating\" (free on its soles, with contact) needs the facts "
                         f"{'; '.join(missing)}")
    builder = builder or DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step)
    if time_step > 0:
        from pydrake.multibody.plant import DiscreteContactApproximation

        plant.set_discrete_contact_approximation(DiscreteContactApproximation.kLagged)
    parser = Parser(plant)
    pm = parser.package_map()
    for name in _package_names(text):
        folder = packages.folder(name)
        if not pm.Contains(name):
            pm.Add(name, str(folder))
    drake_log = logging.getLogger("drake")
    level = drake_log.level
    drake_log.setLevel(logging.ERROR)  # Drake's warnings on tags it ignores (safety_controller, ...)
    try:
        if fmt == "urdf":
            models = parser.AddModelsFromString(text, "urdf")
        else:
            models = parser.AddModels(str(path))
    except RuntimeError as e:
        raise ModelError(f"{path.name}: Drake cannot parse it: {_first_line(e)}") from None
    finally:
        drake_log.setLevel(level)
    notes.extend(_weld_base(plant, models, spec.weld, path, spec.weld_pose))
    joints = [plant.get_joint(JointIndex(i)) for i in range(plant.num_joints())]
    for j in joints:
        kind = j.type_name()
        if kind not in (*ONE_DOF_JOINTS, "weld", "quaternion_floating", "rpy_floating"):
            raise ModelError(f"{path.name}: joint '{j.name()}' is a {kind} joint, which the planning coordinates "
                             "cannot hold (revolute, continuous, prismatic and fixed joints only)")
        if kind in ("quaternion_floating", "rpy_floating"):
            raise ModelError(f"{path.name}: joint '{j.name()}' is a floating joint inside the tree: weld a frame "
                             "to the world (weld = \"<frame>\")")
    planning = [j for j in joints if j.type_name() in ONE_DOF_JOINTS]
    if not planning:
        raise ModelError(f"{path.name}: no revolute, continuous or prismatic joint to plan for")
    if spec.gravity != DRAKE_GRAVITY:
        plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, -spec.gravity])
    if spec.true:
        notes.extend(_apply_true(plant, spec, path, planning))
    limits = {j: dict(v) for j, v in spec.limits}
    names = [j.name() for j in planning]
    for j in limits:
        if j not in names:
            raise ModelError(f"limits: joint '{j}' is not a planning joint of {path.name}: closest {closest_names(j, names)}")
    armature = per_joint(spec.armature, names, "armature")
    for j in spec.unactuated:
        if j not in names:
            raise ModelError(f"unactuated: joint '{j}' is not a planning joint of {path.name}: closest "
                             f"{closest_names(j, names)}")
    unlimited, file_efforts = [], _file_efforts(text, fmt)
    # SDF and MJCF files declare their actuators (URDF transmissions were replaced above): one per joint kept
    existing = {}
    for i in plant.GetJointActuatorIndices():
        act = plant.get_joint_actuator(i)
        if act.joint().index() in existing:
            raise ModelError(f"{path.name}: joint '{act.joint().name()}' has more than one actuator")
        existing[act.joint().index()] = act
    for j, arm in zip(planning, armature):
        act = existing.get(j.index())
        if j.name() in spec.unactuated:  # no motor: no actuator (the file's is refused)
            if act is not None:
                raise ModelError(f"unactuated: joint '{j.name()}' has an actuator in {path.name}; edit the file")
            continue
        effort = float(act.effort_limit()) if act is not None else file_efforts.get(j.name())
        effort = limits.get(j.name(), {}).get("effort", effort)
        if not effort or effort <= 0 or not math.isfinite(effort):
            unlimited.append(j.name())
            effort = math.inf
        if act is None:
            act = plant.AddJointActuator(f"{j.name()}_actuator", j, effort)
        elif effort != act.effort_limit():
            raise ModelError(f"limits: the effort of '{j.name()}' is set by its actuator in {path.name} "
                             f"({act.effort_limit():g}); edit the file")
        act.set_default_gear_ratio(1.0)
        act.set_default_rotor_inertia(arm)
    if unlimited:
        notes.append(f"effort limit 0 or missing on {len(unlimited)} joints ({_names(unlimited)}): unlimited"
                     + (f"; {len(existing)} actuators of the file kept" if existing else ""))
    elif existing:
        notes.append(f"{len(existing)} actuators of the file kept")
    if before_finalize is not None:
        before_finalize(plant, text, path, packages)
    try:
        plant.Finalize()
    except RuntimeError as e:
        raise ModelError(f"{path.name}: Drake cannot build the plant: {_first_line(e)}") from None
    if spec.order == "tree":
        order = np.argsort([j.position_start() for j in planning])
        planning, names = [planning[i] for i in order], [names[i] for i in order]
    n = plant.num_positions()
    if n != len(planning) or plant.num_velocities() != n:
        raise ModelError(f"{path.name}: {n} positions for {len(planning)} planning joints")
    P, planning, names = _coupling(dict(spec.coupled), planning, path)
    lower = np.array([j.position_lower_limits()[0] for j in planning])
    upper = np.array([j.position_upper_limits()[0] for j in planning])
    efforts = np.array([0.0 if j.name() in spec.unactuated else _effort_of(plant, j) for j in planning])
    velocity = np.array([min(-j.velocity_lower_limits()[0], j.velocity_upper_limits()[0]) for j in planning])
    velocity = np.where(velocity > 0, velocity, np.inf)   # 0 or less: no limit stated
    for k, name in enumerate(names):
        lower[k] = limits.get(name, {}).get("lower", lower[k])
        upper[k] = limits.get(name, {}).get("upper", upper[k])
    default = _start_posture(spec, path, names, lower, upper, notes)
    for label, frame in spec.end_effectors + tuple((f, f) for f in spec.hands + spec.feet):
        if not plant.HasFrameNamed(frame):
            raise ModelError(f"frame '{frame}' ({label}) is not in {path.name}: closest "
                             f"{closest_names(frame, frame_names(plant))}")
    robot = Robot(name=spec.plant or f"{path.stem}-{spec_digest(spec, text)}", plant=plant,
                  scene_graph=scene_graph, builder=builder, joint_names=tuple(names), P=P, lower=lower, upper=upper,
                  effort=efforts, default_q=default, spec=spec, B_act=plant.MakeActuationMatrix(), velocity=velocity)
    robot.load_report = notes
    return robot


def _coupling(coupled: dict[str, str], joints: list, path: Path) -> tuple[np.ndarray, list, list[str]]:
    """``(P, planning joints, their names)``: every joint a planning coordinate, except a coupled one, which
    copies the coordinate of the joint it names (one motor drives both). ``P (n_plant, n_q)``."""
    names = [j.name() for j in joints]
    for joint, driver in coupled.items():
        if joint not in names or driver not in names or driver in coupled:
            bad = joint if joint not in names else driver
            raise ModelError(f"coupled: '{joint}' -> '{driver}': '{bad}' is not a free joint of {path.name}: "
                             f"closest {closest_names(bad, names)}")
    planning = [j for j in joints if j.name() not in coupled]
    col = {j.name(): k for k, j in enumerate(planning)}
    P = np.zeros((len(joints), len(planning)))
    for j in joints:
        P[j.position_start(), col[coupled.get(j.name(), j.name())]] = 1.0
    return P, planning, [j.name() for j in planning]


def _package_names(text: str) -> list[str]:
    import re

    return sorted(set(re.findall(r"package://([^/\"'\s]+)/", text)))


def _first_line(e: Exception) -> str:
    lines = [s for s in str(e).splitlines() if s.strip()]
    return lines[0] if lines else type(e).__name__


def _weld_base(plant, models, weld: str | None, path: Path, pose: tuple[float, ...] = ()) -> list[str]:
    """Weld ``weld`` (or a free root body) to the world; the report's line."""
    from pydrake.multibody.tree import JointIndex

    children = {plant.get_joint(JointIndex(i)).child_body().index() for i in range(plant.num_joints())}
    roots = [b for b in (plant.get_body(i) for m in models for i in plant.GetBodyIndices(m))
             if b.index() not in children]
    if weld is not None:
        if not plant.HasFrameNamed(weld):
            raise ModelError(f"weld frame '{weld}' is not in {path.name}: closest "
                             f"{closest_names(weld, frame_names(plant))}")
        from pydrake.math import RigidTransform, RollPitchYaw

        X_WF = RigidTransform(RollPitchYaw(*pose[3:]), list(pose[:3])) if pose else RigidTransform()
        plant.WeldFrames(plant.world_frame(), plant.GetFrameByName(weld), X_WF)
        at = f" at {', '.join(f'{v:g}' for v in pose)}" if pose else ""
        return [f"frame '{weld}' welded to the world{at}" + (" (the root is free in the file)" if roots else "")]
    if len(roots) > 1:
        raise ModelError(f"{path.name}: {len(roots)} bodies are free ({_names([b.name() for b in roots])}): "
                         "weld one frame to the world (weld = \"<frame>\")")
    if roots:
        plant.WeldFrames(plant.world_frame(), roots[0].body_frame())
        return [f"root '{roots[0].name()}' welded to the world at its origin (it is free in the file)"]
    return []


def frame_names(plant) -> list[str]:
    """Every frame's name in ``plant`` (sorted, for the closest-name lists of error lines)."""
    from pydrake.multibody.tree import FrameIndex

    return sorted({plant.get_frame(FrameIndex(i)).name() for i in range(plant.num_frames())})


def _file_efforts(text: str, fmt: str) -> dict[str, float]:
    """``joint -> <limit effort>`` of a URDF's text (none for other formats: their actuators say it)."""
    if fmt != "urdf":
        return {}
    out = {}
    for j in ET.fromstring(text).findall("joint"):
        lim = j.find("limit")
        if lim is not None and lim.get("effort") is not None:
            out[j.get("name")] = float(lim.get("effort"))
    return out


def _effort_of(plant, joint) -> float:
    for i in plant.GetJointActuatorIndices():
        act = plant.get_joint_actuator(i)
        if act.joint().index() == joint.index():
            return float(act.effort_limit())
    return math.inf


def per_joint(value, names: list[str], what: str) -> np.ndarray:
    """``(len(names),)``: ``value`` at every joint (a number) or per joint (a mapping, 0 where not named);
    ``ModelError`` for a negative value or a joint not in ``names``."""
    if isinstance(value, (int, float)):
        if value < 0:
            raise ModelError(f"{what} must be >= 0, got {value}")
        return np.full(len(names), float(value))
    d = dict(value)
    for k, v in d.items():
        if k not in names:
            raise ModelError(f"{what}: joint '{k}' is not a planning joint: closest {closest_names(k, names)}")
        if v < 0:
            raise ModelError(f"{what} of '{k}' must be >= 0, got {v}")
    return np.array([d.get(n, 0.0) for n in names])


def _start_posture(spec: RobotSpec, path: Path, names: list[str], lower, upper, notes: list[str]) -> np.ndarray:
    if isinstance(spec.start, str):
        srdf = Path(spec.srdf) if spec.srdf else default_srdf(path)
        if srdf is None:
            raise ModelError(f"start posture '{spec.start}' needs an SRDF: none found beside {path.name}; "
                             "set srdf = \"<file>\"")
        postures = srdf_postures(srdf)
        if spec.start not in postures:
            raise ModelError(f"start posture '{spec.start}' is not in {srdf.name}: choose one of "
                             f"{', '.join(sorted(postures)) or '(none)'}")
        values = postures[spec.start]
        values = {k: v for k, v in values.items() if k in names}
    else:
        values = dict(spec.start)
        for k in values:
            if k not in names:
                raise ModelError(f"start: joint '{k}' is not a planning joint of {path.name}: closest "
                                 f"{closest_names(k, names)}")
    q = np.array([values.get(n, 0.0) for n in names])
    outside = [n for n, v, lo, hi in zip(names, q, lower, upper) if not lo <= v <= hi]
    if outside:  # kept as stated (crocoddyl's Kinova starts so; a turn further would change its cold start)
        notes.append(f"start posture outside the file's joint limits on {_names(outside)} (kept as stated; "
                     "an execution starts clipped to them; the plan stage says what its bounds make of it)")
    return q


@cache
def shared_model(spec: RobotSpec) -> Robot:
    """One robot per spec and process for kinematics and dynamics queries (not for diagrams)."""
    return load_model(spec)
