"""A scene around a robot and the signed distances between them, from Drake's SceneGraph.

A scene is a list of objects (a problem file's ``[[scene]]`` entries, :func:`normalize_scene`), each
with a ``name`` and a ``pose`` ``[x, y, z, roll, pitch, yaw]`` (m, rad) in the world:

- ``box`` (``size``, 3 edge lengths, m), ``sphere`` (``radius``), ``cylinder`` and ``capsule``
  (``radius``, ``length`` along the object's z axis, m);
- ``mesh`` (``file``: ``.obj``, ``.stl`` or ``.dae``, ``scale``): its convex hull (Drake's ``Convex``);
- ``file``: a URDF or SDF world file (``file``) whose collision geometry is the object; its root
  link welded to the world at ``pose``.

The robot's collision geometry is its model file's own ``<collision>`` elements (kept here, while
the planning plant drops them: :mod:`raico.plants.model_file`), meshes as their convex hulls.

:class:`CollisionWorld` is a MultibodyPlant with the robot and the scene registered in a SceneGraph;
:meth:`CollisionWorld.distances` gives, for a list of geometry pairs, the signed distances (m,
negative in penetration; pairs farther than ``max_distance`` report it and a zero gradient) and their
gradients with respect to the plant's positions, ``dd/dq = n^T (J_A(p_A) - J_B(p_B))``: the witness
points' translational Jacobians (Drake's) projected on the normal ``n`` (from B to A): the reference.
:class:`SignedDistances` is the task map of those distances on planning coordinates, batched over a
trajectory: lower bounds cull the pairs first (bounding spheres and capsules, a scene primitive's distance,
and the last batches' distances less how far the joints moved since times their reach), each remaining pair is one
``ComputeSignedDistancePairClosestPoints``, and the Jacobians come from the compiled kinematics.

Faults (``ValueError``, one line): an unknown key or shape, a non-positive size, a mesh that
cannot be read, a world file that does not parse.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import math
import struct
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from raico.plants.codegen import c_backend

SHAPES: dict[str, set[str]] = {"box": {"size"}, "sphere": {"radius"}, "cylinder": {"radius", "length"},
                               "capsule": {"radius", "length"}, "mesh": {"file", "scale"}, "file": {"file"}}
COMMON_KEYS = {"name", "type", "pose", "color"}
MESH_FORMATS = (".obj", ".stl")
FRICTION = 0.5          # Coulomb friction of the scene's and the robot's contact (execution)
ROBOT_PREFIX = "robot:"  # geometry names of the robot's collision elements: "robot:LINK/i"


# ------------------------------------------------------------------ meshes
def read_mesh(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``(n, 3)`` and triangles ``(m, 3)`` (0-based) of an ``.obj`` or ``.stl`` (binary or ASCII)
    file, or a COLLADA ``.dae`` (through trimesh, its ``Y_UP`` turned to z up as the recordings do);
    ``ValueError`` (one line) where it cannot be read."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (*MESH_FORMATS, ".dae"):
        raise ValueError(f"mesh {path.name}: cannot be read: format '{path.suffix}' (use "
                         f"{', '.join((*MESH_FORMATS, '.dae'))})")
    try:
        stat = path.stat()
    except OSError as e:
        raise ValueError(f"mesh {path}: cannot be read ({e.strerror})") from None
    return _read_mesh(str(path), stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=512)
def _read_mesh(file: str, mtime_ns: int, size: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`read_mesh` of a file as it is (its modification time and size in the key): read once per process."""
    path = Path(file)
    suffix = path.suffix.lower()
    try:
        data = path.read_bytes()
    except OSError as e:
        raise ValueError(f"mesh {path}: cannot be read ({e.strerror})") from None
    try:
        V, F = (_read_obj(data) if suffix == ".obj" else _read_stl(data) if suffix == ".stl" else _read_dae(path))
    except (ValueError, IndexError, struct.error) as e:
        raise ValueError(f"mesh {path.name}: cannot be read ({e})") from None
    if len(V) < 4 or not np.all(np.isfinite(V)) or np.linalg.matrix_rank(V - V.mean(0), tol=1e-9) < 3:
        raise ValueError(f"mesh {path.name}: cannot be read (fewer than 4 vertices off one plane, or not finite)")
    V.flags.writeable = False
    F.flags.writeable = False
    return V, F


def _read_obj(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    V: list[list[float]] = []
    F: list[list[int]] = []
    for line in data.decode("utf-8", errors="strict").splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            V.append([float(x) for x in parts[1:4]])
        elif parts[0] == "f":
            idx = [int(p.split("/")[0]) for p in parts[1:]]
            idx = [i - 1 if i > 0 else len(V) + i for i in idx]
            F.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
    return np.asarray(V, dtype=float).reshape(-1, 3), np.asarray(F, dtype=np.int64).reshape(-1, 3)


def _read_stl(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    if len(data) >= 84:
        n = struct.unpack("<I", data[80:84])[0]
        if len(data) == 84 + 50 * n:   # binary: a 50-byte record per triangle
            rec = np.frombuffer(data, dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]),
                                count=n, offset=84)
            V = rec["v"].reshape(-1, 3).astype(float)
            return V, np.arange(3 * n).reshape(-1, 3)
    text = data.decode("ascii")
    if not text.lstrip().startswith("solid"):
        raise ValueError("neither binary nor ASCII STL")
    rows = [[float(x) for x in line.split()[1:4]] for line in text.splitlines() if line.strip().startswith("vertex")]
    return np.asarray(rows, dtype=float).reshape(-1, 3), np.arange(len(rows)).reshape(-1, 3)


def _read_dae(path: Path) -> tuple[np.ndarray, np.ndarray]:
    import logging

    import trimesh

    logging.getLogger("trimesh").setLevel(logging.ERROR)
    try:
        m = trimesh.load(str(path), force="mesh", process=False)
    except Exception as e:  # noqa: BLE001 - any reader failure is this mesh's fault: one line
        raise ValueError(f"{type(e).__name__}") from None
    V, F = np.asarray(m.vertices, float), np.asarray(m.faces, int)
    with open(path, "rb") as f:
        if b"<up_axis>Y_UP</up_axis>" in f.read(4096):
            V = V[:, [0, 2, 1]] * np.array([1.0, -1.0, 1.0])
    return V, F


def obj_text(V: np.ndarray, F: np.ndarray) -> str:
    """An ``.obj`` file's text of vertices ``V (n, 3)`` and triangles ``F (m, 3)``."""
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in V] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ problem-file entries
def _positive(v, what: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < math.inf:
        raise ValueError(f"{what} must be a number > 0 (m), got {v!r}")
    return float(v)


def _pose(v, where: str) -> list[float]:
    if v is None:
        return [0.0] * 6
    if (not isinstance(v, list) or len(v) != 6
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)):
        raise ValueError(f"{where} pose must be [x, y, z, roll, pitch, yaw] (m, rad), got {v!r}")
    return [float(x) for x in v]


def normalize_scene(entries, base: Path, resolve=None) -> list[dict]:
    """The canonical scene of a problem file's ``[[scene]]`` entries (paths resolved against ``base``
    or by ``resolve(uri) -> Path`` for ``package://`` URIs, files read and hashed, keys checked)."""
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise ValueError("[[scene]] must be an array of tables, each with a name and a type")
    out, names = [], set()
    for i, e in enumerate(entries):
        name = e.get("name")
        where = f"[[scene]] '{name}'" if isinstance(name, str) else f"[[scene]] entry {i + 1}"
        if not isinstance(name, str) or not name or ROBOT_PREFIX in name or "/" in name:
            raise ValueError(f"{where}: needs a name (a string without '/' or '{ROBOT_PREFIX}')")
        if name in names:
            raise ValueError(f"{where}: the name is used twice")
        names.add(name)
        kind = e.get("type")
        if kind not in SHAPES:
            raise ValueError(f"{where}: unknown type {kind!r}: choose one of {', '.join(SHAPES)}")
        unknown = sorted(set(e) - COMMON_KEYS - SHAPES[kind])
        if unknown:
            raise ValueError(f"{where} ({kind}): unknown key '{unknown[0]}': valid keys are "
                             f"{', '.join(sorted(COMMON_KEYS | SHAPES[kind]))}")
        d: dict[str, Any] = {"name": name, "type": kind, "pose": _pose(e.get("pose"), where)}
        if "color" in e:
            c = e["color"]
            if not isinstance(c, list) or len(c) not in (3, 4) or not all(isinstance(x, (int, float)) and 0 <= x <= 1
                                                                          for x in c):
                raise ValueError(f"{where}: color must be [r, g, b] or [r, g, b, a] in [0, 1]")
            d["color"] = [float(x) for x in c]
        if kind == "box":
            size = e.get("size")
            if not isinstance(size, list) or len(size) != 3:
                raise ValueError(f"{where}: a box needs size = [x, y, z] (m)")
            d["size"] = [_positive(s, f"{where} size") for s in size]
        if kind in ("sphere", "cylinder", "capsule"):
            d["radius"] = _positive(e.get("radius"), f"{where} radius")
        if kind in ("cylinder", "capsule"):
            d["length"] = _positive(e.get("length"), f"{where} length")
        if kind in ("mesh", "file"):
            f = e.get("file")
            if not isinstance(f, str):
                raise ValueError(f"{where}: needs a file")
            path = resolve(f) if (resolve is not None and f.startswith("package://")) else (base / f).resolve()
            if kind == "mesh":
                read_mesh(path)
                d["scale"] = _positive(e.get("scale", 1.0), f"{where} scale")
            else:
                check_world_file(path, where)
            d["file"] = str(path)
            d["sha256"] = hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]
        out.append(d)
    return out


def check_world_file(path: Path, where: str) -> None:
    """``ValueError`` unless Drake parses the URDF or SDF world file ``path`` into a plant."""
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.systems.framework import DiagramBuilder

    if not path.is_file():
        raise ValueError(f"{where}: world file not found: {path}")
    if path.suffix.lower() not in (".urdf", ".sdf"):
        raise ValueError(f"{where}: a world file is a .urdf or .sdf, got '{path.suffix}'")
    plant, _ = AddMultibodyPlantSceneGraph(DiagramBuilder(), 0.0)
    try:
        _add_world_file(plant, path, [0.0] * 6)
    except (RuntimeError, ValueError) as e:
        raise ValueError(f"{where}: world file {path.name} does not parse: {str(e).splitlines()[0]}") from None


# ------------------------------------------------------------------ geometry
def rigid_transform(pose):
    """Drake's ``RigidTransform`` of ``[x, y, z, roll, pitch, yaw]`` (m, rad)."""
    from pydrake.math import RigidTransform, RollPitchYaw

    return RigidTransform(RollPitchYaw(*pose[3:]), np.asarray(pose[:3], float))


@dataclass(frozen=True)
class Shape:
    """One collision geometry: ``kind`` (box, sphere, cylinder, capsule, convex), its sizes (m),
    ``pose`` ``[x, y, z, roll, pitch, yaw]`` in its body's frame (the world's for the scene), and a
    convex mesh's vertices and triangles (already scaled, m)."""

    name: str
    body: str                       # link name, or "world"
    kind: str
    pose: tuple[float, ...]
    size: tuple[float, ...] = ()    # box: 3 edges; sphere: (r,); cylinder, capsule: (r, length)
    vertices: Any = None
    faces: Any = None
    color: tuple[float, ...] | None = None

    def drake_shape(self):
        from pydrake.common import MemoryFile
        from pydrake.geometry import Box, Capsule, Convex, Cylinder, InMemoryMesh, Sphere

        if self.kind == "box":
            return Box(*self.size)
        if self.kind == "sphere":
            return Sphere(self.size[0])
        if self.kind == "cylinder":
            return Cylinder(*self.size)
        if self.kind == "capsule":
            return Capsule(*self.size)
        text = obj_text(np.asarray(self.vertices), np.asarray(self.faces))
        return Convex(InMemoryMesh(mesh_file=MemoryFile(text, ".obj", self.name)))


def scene_shapes(scene: list[dict]) -> list[Shape]:
    """The shapes of a canonical scene's primitive and mesh objects (world files: in :class:`CollisionWorld`)."""
    out = []
    for d in scene:
        color = tuple(d["color"]) if "color" in d else None
        pose = tuple(d["pose"])
        if d["type"] == "box":
            out.append(Shape(d["name"], "world", "box", pose, tuple(d["size"]), color=color))
        elif d["type"] == "sphere":
            out.append(Shape(d["name"], "world", "sphere", pose, (d["radius"],), color=color))
        elif d["type"] in ("cylinder", "capsule"):
            out.append(Shape(d["name"], "world", d["type"], pose, (d["radius"], d["length"]), color=color))
        elif d["type"] == "mesh":
            V, F = read_mesh(d["file"])
            out.append(Shape(d["name"], "world", "convex", pose, vertices=V * d["scale"], faces=F, color=color))
    return out


def bounding_sphere(s: Shape) -> tuple[np.ndarray, float]:
    """A sphere around shape ``s``: its centre ``(3,)`` in the shape's frame and radius (m)."""
    if s.kind == "box":
        return np.zeros(3), 0.5 * float(np.linalg.norm(s.size))
    if s.kind == "sphere":
        return np.zeros(3), s.size[0]
    if s.kind == "capsule":
        return np.zeros(3), s.size[0] + 0.5 * s.size[1]
    if s.kind == "cylinder":
        return np.zeros(3), math.hypot(s.size[0], 0.5 * s.size[1])
    V = np.asarray(s.vertices)
    c = 0.5 * (V.min(0) + V.max(0))
    return c, float(np.linalg.norm(V - c, axis=1).max())


def bounding_capsule(s: Shape) -> tuple[np.ndarray, np.ndarray, float]:
    """A capsule around shape ``s``: its segment's ends ``(3,)``, ``(3,)`` in the shape's frame and its radius (m).
    A capsule or a sphere is its own; a cylinder the capsule of its radius and length; a box or a convex mesh
    one along the principal axis of its vertices, the radius their largest distance from that axis and the
    segment as short as keeps every vertex inside (then the hull: a capsule is convex)."""
    if s.kind == "sphere":
        return np.zeros(3), np.zeros(3), s.size[0]
    if s.kind in ("capsule", "cylinder"):
        h = np.array([0.0, 0.0, 0.5 * s.size[1]])
        return -h, h, s.size[0]
    if s.kind == "box":
        V = 0.5 * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * np.asarray(s.size)
    else:
        V = np.asarray(s.vertices, float)
    c = V.mean(axis=0)
    axis = np.linalg.eigh(np.cov((V - c).T) + 1e-300 * np.eye(3))[1][:, -1]
    along = (V - c) @ axis
    rho = np.linalg.norm((V - c) - along[:, None] * axis, axis=1)
    r = float(rho.max()) * (1 + 1e-12) + 1e-12
    reach = np.sqrt(np.maximum(r * r - rho * rho, 0.0))
    # vertex v is inside where the segment [s0, s1] meets [along_v - reach_v, along_v + reach_v]: s0 <= min(along +
    # reach), s1 >= max(along - reach); the shortest such segment, a point where those overlap
    top, bottom = float(np.max(along - reach)), float(np.min(along + reach))
    s0, s1 = (bottom, top) if top > bottom else (0.5 * (top + bottom),) * 2
    return c + s0 * axis, c + s1 * axis, r


def segment_distances(P0: np.ndarray, P1: np.ndarray, Q0: np.ndarray, Q1: np.ndarray) -> np.ndarray:
    """Distances ``(...)`` between the segments ``P0 P1`` and ``Q0 Q1`` (``(..., 3)`` each; a segment may be a
    point): the closest points' parameters clamped to ``[0, 1]`` one after the other (Ericson, *Real-Time
    Collision Detection*, 5.1.9)."""
    d1, d2, r = P1 - P0, Q1 - Q0, P0 - Q0
    a, e = np.einsum("...i,...i", d1, d1), np.einsum("...i,...i", d2, d2)
    b, c, f = np.einsum("...i,...i", d1, d2), np.einsum("...i,...i", d1, r), np.einsum("...i,...i", d2, r)
    tiny = 1e-30
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = a * e - b * b
        s = np.where(denom > tiny * np.maximum(a * e, tiny), np.clip((b * f - c * e) / denom, 0.0, 1.0), 0.0)
        point_q = e <= tiny   # Q a point: t = 0, s its projection on P
        t = np.where(point_q, 0.0, (b * s + f) / e)
        s = np.where(point_q | (t < 0.0), np.where(a > tiny, np.clip(-c / a, 0.0, 1.0), 0.0),
                     np.where(t > 1.0, np.where(a > tiny, np.clip((b - c) / a, 0.0, 1.0), 0.0), s))
        t = np.clip(t, 0.0, 1.0)
    return np.linalg.norm(r + d1 * s[..., None] - d2 * t[..., None], axis=-1)


@functools.lru_cache(maxsize=1024)
def _pose_matrix(pose: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    X = rigid_transform(pose)
    return X.rotation().matrix(), X.translation()


def point_distance(s: Shape, P: np.ndarray) -> np.ndarray:
    """Signed distances ``(K,)`` (m) of world points ``P (K, 3)`` to the primitive ``s`` placed in the world
    (box, sphere, cylinder, capsule; negative inside)."""
    R, p = _pose_matrix(tuple(s.pose))
    L = (P - p) @ R     # in the shape's frame
    if s.kind == "sphere":
        return np.linalg.norm(L, axis=1) - s.size[0]
    if s.kind == "capsule":
        z = np.clip(L[:, 2], -0.5 * s.size[1], 0.5 * s.size[1])
        return np.linalg.norm(L - np.c_[np.zeros((len(L), 2)), z], axis=1) - s.size[0]
    if s.kind == "box":
        q = np.abs(L) - 0.5 * np.asarray(s.size)
    elif s.kind == "cylinder":
        q = np.c_[np.hypot(L[:, 0], L[:, 1]) - s.size[0], np.abs(L[:, 2]) - 0.5 * s.size[1]]
    else:
        raise ValueError(f"point_distance: no formula for a {s.kind}")
    return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)


def _floats(text: str | None, n: int, default: float = 0.0) -> list[float]:
    vals = [float(x) for x in (text or "").split()]
    return vals if len(vals) == n else [default] * n


def urdf_collisions(text: str, path: Path, resolve) -> list[Shape]:
    """The ``<collision>`` elements of a URDF's text as shapes on their links (meshes as their convex
    hulls; ``resolve(uri) -> Path`` finds a mesh file); a mesh that cannot be read is a ``ValueError``."""
    root = ET.fromstring(text)
    out = []
    for link in root.findall("link"):
        for i, c in enumerate(link.findall("collision")):
            o = c.find("origin")
            pose = tuple(_floats(o.get("xyz") if o is not None else None, 3)
                         + _floats(o.get("rpy") if o is not None else None, 3))
            g = c.find("geometry")
            el = next(iter(g), None) if g is not None else None
            name = f"{ROBOT_PREFIX}{link.get('name')}/{i}"
            if el is None:
                continue
            if el.tag == "box":
                out.append(Shape(name, link.get("name"), "box", pose, tuple(_floats(el.get("size"), 3))))
            elif el.tag == "sphere":
                out.append(Shape(name, link.get("name"), "sphere", pose, (float(el.get("radius")),)))
            elif el.tag in ("cylinder", "capsule"):
                out.append(Shape(name, link.get("name"), el.tag, pose, (float(el.get("radius")), float(el.get("length")))))
            elif el.tag == "mesh":
                f = resolve(el.get("filename"), path.parent)
                V, F = read_mesh(f)
                scale = np.asarray(_floats(el.get("scale"), 3, 1.0))
                out.append(Shape(name, link.get("name"), "convex", pose, vertices=V * scale, faces=F))
            else:
                raise ValueError(f"{path.name}: link '{link.get('name')}': collision geometry <{el.tag}> is not supported")
    return out


def _add_world_file(plant, path: Path, pose) -> list:
    """Parse a URDF/SDF world file into ``plant``, its first body welded to the world at ``pose``; its model
    instances."""
    from pydrake.multibody.parsing import Parser

    parser = Parser(plant, f"scene_{hashlib.sha256(str(path).encode()).hexdigest()[:8]}")
    models = parser.AddModels(str(path))
    for m in models:
        bodies = plant.GetBodyIndices(m)
        if bodies:
            body = plant.get_body(bodies[0])
            if not plant.HasJointNamed(body.name(), m):
                try:
                    plant.WeldFrames(plant.world_frame(), body.body_frame(), rigid_transform(pose))
                except RuntimeError:  # the file attaches it to the world itself
                    pass
    return models


def proximity_properties():
    """Contact properties of every collision geometry: point contact with Coulomb friction FRICTION
    (hydroelastic where Drake falls back: ``kHydroelasticWithFallback`` uses point contact for shapes
    without a hydroelastic representation)."""
    from pydrake.geometry import AddContactMaterial, ProximityProperties
    from pydrake.multibody.plant import CoulombFriction

    props = ProximityProperties()
    AddContactMaterial(friction=CoulombFriction(FRICTION, FRICTION), properties=props)
    return props


def register_scene(scene: list[dict], robot_shapes: list[Shape] | None = None):
    """A ``before_finalize`` hook (``raico.plants.model_file.load_model``) that registers the robot's
    ``robot_shapes`` on its links and the scene's objects on the world, with contact properties."""

    def hook(plant, text, path, packages) -> None:
        props = proximity_properties()
        for s in robot_shapes or []:
            body = plant.GetBodyByName(s.body)
            plant.RegisterCollisionGeometry(body, rigid_transform(s.pose), s.drake_shape(), s.name, props)
        for s in scene_shapes(scene):
            plant.RegisterCollisionGeometry(plant.world_body(), rigid_transform(s.pose), s.drake_shape(), s.name, props)
        for d in scene:
            if d["type"] == "file":
                _add_world_file(plant, Path(d["file"]), d["pose"])
    return hook


def robot_shapes(spec) -> list[Shape]:
    """The robot's own collision geometry (its URDF's ``<collision>`` elements; other formats: none
    here, Drake registers theirs when it parses them)."""
    from raico.plants.model_file import Packages

    path = Path(spec.file)
    if path.suffix.lower() != ".urdf":
        return []
    text = path.read_text(errors="replace").replace("package:///", "package://")
    packages = Packages(dict(spec.packages), path)
    return urdf_collisions(text, path, packages.resolve)


# ------------------------------------------------------------------ the compiled distances (distance.c)
GJK_EPS = 1e-12      # distance.c's convergence: ||v||^2 - v.w <= eps ||v||^2 (the distance within eps of its bound)
GJK_TINY = 1e-6      # m: cores closer than this (or overlapping) go to Drake (penetration)
GJK_GAP = 1e-9      # m: a stop (rounding) with the distance more than this above GJK's lower bound goes to Drake
GJK_MAX_ITER = 128
KNOWN_KEPT = 4       # SignedDistances bounds a batch by its last batches' bounds (a merit's trials near each other)
BATCHES_KEPT = 6     # SignedDistances keeps its last batches (a merit asks again for an iterate it had)
GJK_KINDS = {"convex": 0, "box": 1, "sphere": 2, "capsule": 3, "cylinder": 4}


#: ``distance.c`` compiled (``ctypes``), or None where compiled kernels are off or unavailable.
gjk_library = c_backend.CompiledLibrary("distance", lambda: c_backend.c_source(__file__, "distance.c"), {
    "gjk_batch": ([ctypes.c_long] + [ctypes.c_void_p] * 8 + [ctypes.c_long] + [ctypes.c_void_p] * 8
                  + [ctypes.c_double] * 3 + [ctypes.c_long] + [ctypes.c_void_p] * 5, ctypes.c_long),
    "gjk_frames_batch": ([ctypes.c_long] + [ctypes.c_void_p] * 2 + [ctypes.c_long] + [ctypes.c_void_p] * 2
                         + [ctypes.c_long] + [ctypes.c_void_p] * 3 + [ctypes.c_long, ctypes.c_void_p, ctypes.c_long]
                         + [ctypes.c_void_p] * 2 + [ctypes.c_long] + [ctypes.c_void_p] * 9 + [ctypes.c_double] * 3
                         + [ctypes.c_long] + [ctypes.c_void_p] * 5, ctypes.c_long),
    "gjk_support": ([ctypes.c_long] + [ctypes.c_void_p] * 7 + [ctypes.c_long, ctypes.c_void_p], None)})


@functools.lru_cache(maxsize=256)
def _hull(key: bytes, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    from scipy.spatial import ConvexHull

    V = np.frombuffer(key).reshape(n, 3)
    h = ConvexHull(V)
    idx = np.asarray(h.vertices)
    local = np.full(n, -1)
    local[idx] = np.arange(len(idx))
    T = local[np.asarray(h.simplices)]
    E = np.unique(np.sort(np.vstack([T[:, [0, 1]], T[:, [1, 2]], T[:, [0, 2]]]), axis=1), axis=0)
    E = np.vstack([E, E[:, ::-1]])
    E = E[np.lexsort((E[:, 1], E[:, 0]))]
    start = np.searchsorted(E[:, 0], np.arange(len(idx) + 1))
    return np.ascontiguousarray(V[idx]), start.astype(np.int64), E[:, 1].astype(np.int64)


def hull_graph(V: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The convex hull of points ``V (n, 3)``: its vertices ``(h, 3)`` and their neighbours along the hull's
    (triangulated) edges as ``start (h + 1,)``, ``adj``: vertex ``i``'s neighbours are ``adj[start[i]:start[i+1]]``."""
    V = np.ascontiguousarray(V, dtype=float)
    return _hull(V.tobytes(), len(V))


class GJKShapes:
    """The shapes of a list of geometries in ``distance.c``'s tables (``None`` for a geometry it has no
    kind for: a world file's): ``kinds``, ``params (n, 4)``, ``vstart``, ``V``, ``astart``, ``adj`` and
    ``spheres (n, 4)`` (a bounding sphere's centre in the shape's frame and radius: :func:`bounding_sphere`)."""

    def __init__(self, shapes: list[Shape | None]):
        kinds: list[int] = []
        params: list[np.ndarray] = []
        Vs: list[np.ndarray] = []
        starts: list[np.ndarray] = []
        adjs: list[np.ndarray] = []
        spheres: list[list[float]] = []
        vstart, off = [0], 0
        self.known = np.array([s is not None and s.kind in GJK_KINDS for s in shapes])
        for s in shapes:
            k = GJK_KINDS.get(s.kind, -1) if s is not None else -1
            kinds.append(k)
            prm = np.zeros(4)
            if k == 0:
                V, start, adj = hull_graph(np.asarray(s.vertices, float))
                Vs.append(V)
                starts.append(start[:-1] + sum(len(a) for a in adjs))
                adjs.append(adj + off)
                off += len(V)
            elif k == 1:
                prm[:3] = 0.5 * np.asarray(s.size)
            elif k == 2:
                prm[3] = s.size[0]
            elif k in (3, 4):
                prm[0], prm[2], prm[3] = s.size[0], 0.5 * s.size[1], s.size[0]
            params.append(prm)
            vstart.append(off)
            c, r = bounding_sphere(s) if k >= 0 else (np.zeros(3), math.inf)
            spheres.append([*c, r * (1 + 1e-12) + 1e-12])   # rounding: never inside the shape
        self.kinds = np.array(kinds, np.int64)
        self.params = np.ascontiguousarray(params, float).reshape(-1, 4)
        self.vstart = np.array(vstart, np.int64)
        self.V = np.ascontiguousarray(np.vstack(Vs) if Vs else np.zeros((0, 3)))
        total = sum(len(a) for a in adjs)
        self.astart = np.array([*(int(x) for st in starts for x in st), total], np.int64)
        self.adj = np.ascontiguousarray(np.concatenate(adjs) if adjs else np.zeros(0, np.int64), np.int64)
        self.spheres = np.ascontiguousarray(spheres, float).reshape(-1, 4)

    def _tables(self):
        return (self.kinds.ctypes.data, self.params.ctypes.data, self.vstart.ctypes.data, self.V.ctypes.data,
                self.astart.ctypes.data, self.adj.ctypes.data)

    def support(self, g: int, d: np.ndarray, hint: int = 0) -> np.ndarray:
        """Shape ``g``'s core's support point (its frame) in the direction ``d (3,)`` (its frame)."""
        d, s = np.ascontiguousarray(d, float), np.zeros(3)
        gjk_library().gjk_support(int(g), d.ctypes.data, *self._tables(), int(hint), s.ctypes.data)
        return s

    def distances(self, ga, gb, RA, pA, RB, pB, limit=np.inf, key=None, hints=None):
        """GJK on queries ``ga``, ``gb`` (shape indices, ``(k,)``) at world poses ``RA (k, 3, 3)``, ``pA (k, 3)``
        (B alike), stopped where a separating plane puts a pair at least ``limit`` (m, ``(k,)`` or a number) apart, query ``i``'s support searches started at ``hints[key[i]]`` (``hints (h, 2)``, vertex indices,
        updated in place to the last support vertices: the start of the key's next query, a nearby posture;
        None: each query its own key, from vertex 0): distances ``(k,)``, witness points in the shapes' frames ``(k, 3)`` twice, normals from B to
        A ``(k, 3)`` (world) and the statuses ``(k,)`` (0 done; 3 beyond ``limit``, the distance that lower bound; 1, 2:
        penetration or no convergence, the pair goes to Drake)."""
        k = len(ga)
        ga, gb = np.ascontiguousarray(ga, np.int64), np.ascontiguousarray(gb, np.int64)
        if k and (ga.min() < 0 or gb.min() < 0 or max(ga.max(), gb.max()) >= len(self.kinds)
                  or not (self.known[ga].all() and self.known[gb].all())):
            raise ValueError("GJKShapes.distances: a shape index out of range or of no kind")
        RA, pA, RB, pB = (np.ascontiguousarray(a, float) for a in (RA, pA, RB, pB))
        from raico.plants.codegen.c_backend import check_shapes

        hints = np.zeros((k, 2), np.int64) if hints is None else hints
        key = np.arange(k) if key is None else np.ascontiguousarray(key, np.int64)
        limit = np.ascontiguousarray(np.broadcast_to(np.asarray(limit, float), (k,)))
        check_shapes("gjk_batch", RA=(RA, (k, 3, 3)), pA=(pA, (k, 3)), RB=(RB, (k, 3, 3)), pB=(pB, (k, 3)),
                     hints=(hints, (len(hints), 2)), key=(key, (k,)))
        if hints.dtype != np.int64 or not hints.flags.c_contiguous or (k and not 0 <= key.min() <= key.max() < len(hints)):
            raise ValueError("GJKShapes.distances: hints must be a C-contiguous int64 array (h, 2), keys in [0, h)")
        dist, wa, wb, nrm = np.empty(k), np.empty((k, 3)), np.empty((k, 3)), np.empty((k, 3))
        status = np.empty(k, np.int64)
        gjk_library().gjk_batch(k, ga.ctypes.data, gb.ctypes.data, RA.ctypes.data, pA.ctypes.data, RB.ctypes.data,
                                pB.ctypes.data, limit.ctypes.data, key.ctypes.data, len(hints), hints.ctypes.data,
                                *self._tables(), self.spheres.ctypes.data, GJK_EPS, GJK_TINY, GJK_GAP, GJK_MAX_ITER,
                                dist.ctypes.data, wa.ctypes.data, wb.ctypes.data, nrm.ctypes.data,
                                status.ctypes.data)
        return dist, wa, wb, nrm, status


    def frames_distances(self, tq, pq, ia, ib, gbody, R_BG, p_BG, rowmap, fr, Jf, limit, hints):
        """GJK on the pairs ``pq (k,)`` (geometries ``ia[pq]``, ``ib[pq]``, shape indices) at the rows ``tq (k,)``
        of a batch, their poses from the bodies' frames: geometry ``g`` on column ``gbody[g]`` of the frames (-1:
        the world), at ``R_BG[g]``, ``p_BG[g]`` in it; ``fr (r, nb, 4, 3)`` the bodies' origins and axes' tips,
        ``Jf (r, nb, 12, m)`` their Jacobians (None: no gradient rows), row ``t`` at ``rowmap[t]``; ``limit``,
        ``hints`` (per pair) as :meth:`distances`. Returns distances ``(k,)``, witness points in the world
        ``(k, 2, 3)``, normals from B to A ``(k, 3)``, gradient rows ``n . (J_A(p_A) - J_B(p_B)) (k, m)`` (None
        without ``Jf``) and the statuses (as :meth:`distances`; the points and rows written where 0)."""
        k = len(tq)
        tq, pq, ia, ib, gbody, rowmap = (np.ascontiguousarray(a, np.int64) for a in (tq, pq, ia, ib, gbody, rowmap))
        R_BG, p_BG, fr = (np.ascontiguousarray(a, float) for a in (R_BG, p_BG, fr))
        n, nr, nbf = len(gbody), len(fr), (fr.shape[1] if fr.ndim == 4 else 0)
        m = Jf.shape[-1] if Jf is not None else 0
        from raico.plants.codegen.c_backend import check_shapes

        limit = np.ascontiguousarray(np.broadcast_to(np.asarray(limit, float), (k,)))
        check_shapes("gjk_frames_batch", tq=(tq, (k,)), pq=(pq, (k,)), ib=(ib, ia.shape), R_BG=(R_BG, (n, 3, 3)),
                     p_BG=(p_BG, (n, 3)), fr=(fr, (nr, nbf, 4, 3)), hints=(hints, (len(ia), 2)))
        if Jf is not None:
            Jf = np.ascontiguousarray(Jf, float)
            check_shapes("gjk_frames_batch", Jf=(Jf, (nr, nbf, 12, m)))
        if (n != len(self.kinds) or hints.dtype != np.int64 or not hints.flags.c_contiguous
                or (len(ia) and (min(ia.min(), ib.min()) < 0 or max(ia.max(), ib.max()) >= n))
                or (k and (pq.min() < 0 or pq.max() >= len(ia))) or (n and gbody.min() < -1)
                or (len(rowmap) and rowmap.max() >= nr) or not (self.known[ia[pq]].all() and self.known[ib[pq]].all())):
            raise ValueError("GJKShapes.frames_distances: a geometry, body column or row out of range or of no kind")
        dist, W, nrm, status = np.empty(k), np.full((k, 2, 3), np.nan), np.empty((k, 3)), np.empty(k, np.int64)
        J = np.empty((k, m)) if Jf is not None else None
        gjk_library().gjk_frames_batch(k, tq.ctypes.data, pq.ctypes.data, len(ia), ia.ctypes.data, ib.ctypes.data,
                                       n, gbody.ctypes.data, R_BG.ctypes.data, p_BG.ctypes.data, len(rowmap),
                                       rowmap.ctypes.data, nbf, fr.ctypes.data, None if Jf is None else Jf.ctypes.data,
                                       m, limit.ctypes.data, hints.ctypes.data, *self._tables(),
                                       self.spheres.ctypes.data, GJK_EPS, GJK_TINY, GJK_GAP, GJK_MAX_ITER,
                                       dist.ctypes.data, W.ctypes.data, nrm.ctypes.data,
                                       None if J is None else J.ctypes.data, status.ctypes.data)
        return dist, W, nrm, J, status


# ------------------------------------------------------------------ the collision world
class CollisionWorld:
    """The robot of ``spec`` with its collision geometry and the ``scene``, in one plant and SceneGraph
    (continuous, for queries). ``geometries``: name -> GeometryId; ``body_of``: name -> the body (link)
    name, ``"world"`` for the scene; ``shapes``: the robot's and the scene's :class:`Shape` (a world
    file's geometry by its name ``OBJECT/GEOMETRY``, no shape)."""

    def __init__(self, spec, scene: list[dict]):
        from pydrake.geometry import Role
        from pydrake.systems.framework import DiagramBuilder

        from raico.plants.model_file import load_model

        self.scene = scene
        shapes = robot_shapes(spec)
        builder = DiagramBuilder()
        self.robot = robot = load_model(spec.planning if hasattr(spec, "planning") else spec, builder, 0.0,
                                        register_scene(scene, shapes))
        self.plant, self.scene_graph = robot.plant, robot.scene_graph
        self.diagram = builder.Build()
        self.context = self.diagram.CreateDefaultContext()
        self.plant_context = self.plant.GetMyMutableContextFromRoot(self.context)
        self.sg_context = self.scene_graph.GetMyContextFromRoot(self.context)
        self.inspector = self.scene_graph.model_inspector()
        self.shapes = shapes + scene_shapes(scene)
        self.shapes_by_name = {s.name: s for s in self.shapes}
        self.geometries: dict[str, Any] = {}
        self.body_of: dict[str, str] = {}
        self.object_of: dict[str, str] = {}   # geometry name -> scene object name (robot geometry: link name)
        self.fixed_pose: dict[str, Any] = {}  # a world file's geometry -> its pose in the world (RigidTransform)
        world_files = {d["name"]: d for d in scene if d["type"] == "file"}
        robot_names = {s.name for s in shapes}
        scene_names = {s.name for s in self.shapes if s.body == "world"}
        for gid in self.inspector.GetAllGeometryIds(Role.kProximity):
            name = self.inspector.GetName(gid).split("::")[-1]   # without its model instance's scope
            body = self.plant.GetBodyFromFrameId(self.inspector.GetFrameId(gid))
            bname = "world" if body is None or body.index() == self.plant.world_body().index() else body.name()
            if name.startswith(ROBOT_PREFIX) or name in robot_names:
                self.object_of[name] = bname
            elif name in scene_names:
                self.object_of[name] = name
            else:
                inst = self.plant.GetModelInstanceName(body.model_instance()) if body is not None else ""
                owner = next((n for n, d in world_files.items() if inst.startswith("scene_")
                              and self._instance_of_file(body.model_instance(), d)), None)
                if owner is None:   # geometry Drake registered from the robot's own (SDF, MJCF) file
                    name = f"{ROBOT_PREFIX}{bname}/{name}"
                    self.object_of[name] = bname
                else:   # welded to the world: fixed, its pose in the world kept
                    name = f"{owner}/{name}"
                    self.object_of[name] = owner
                    bname = "world"
                    self.fixed_pose[name] = self.plant.EvalBodyPoseInWorld(self.plant_context, body).multiply(
                        self.inspector.GetPoseInFrame(gid))
            self.geometries[name] = gid
            self.body_of[name] = bname
        by_name = self.shapes_by_name
        self.bounds: dict[str, tuple[np.ndarray, float]] = {}   # name -> (centre in its body's frame, radius)
        self.capsules: dict[str, tuple[np.ndarray, np.ndarray, float]] = {}   # name -> (ends in its body's frame, r)
        for name in self.geometries:
            shape = by_name.get(name)
            if shape is None:   # a world file's geometry, or one Drake registered: never culled early
                self.bounds[name] = (np.zeros(3), math.inf)
                self.capsules[name] = (np.zeros(3), np.zeros(3), math.inf)
                continue
            c_G, r = bounding_sphere(shape)
            X = rigid_transform(shape.pose)
            R, p = X.rotation().matrix(), X.translation()
            self.bounds[name] = (R @ c_G + p, r)
            a, b, rc = bounding_capsule(shape)
            self.capsules[name] = (R @ a + p, R @ b + p, rc)

    def _instance_of_file(self, instance, d: dict) -> bool:
        tag = f"scene_{hashlib.sha256(d['file'].encode()).hexdigest()[:8]}"
        return self.plant.GetModelInstanceName(instance).startswith(tag)

    # -- names
    def robot_links(self) -> list[str]:
        """Links of the robot that carry collision geometry (model order)."""
        return list(dict.fromkeys(b for n, b in self.body_of.items() if n.startswith(ROBOT_PREFIX)))

    def scene_objects(self) -> list[str]:
        """The scene's object names."""
        return list(dict.fromkeys(o for n, o in self.object_of.items() if not n.startswith(ROBOT_PREFIX)))

    def link_geometries(self, link: str) -> list[str]:
        return [n for n, b in self.body_of.items() if n.startswith(ROBOT_PREFIX) and b == link]

    def object_geometries(self, obj: str) -> list[str]:
        return [n for n, o in self.object_of.items() if not n.startswith(ROBOT_PREFIX) and o == obj]

    def adjacent(self) -> set[frozenset[str]]:
        """Pairs of links that are adjacent: welded together (fixed joints make one rigid group) or in two
        groups a moving joint connects."""
        from pydrake.multibody.tree import JointIndex

        joints = [self.plant.get_joint(JointIndex(i)) for i in range(self.plant.num_joints())]
        group: dict[str, str] = {}

        def root(b: str) -> str:
            while group.get(b, b) != b:
                b = group[b]
            return b

        for j in joints:
            if j.type_name() == "weld":
                a, b = root(j.parent_body().name()), root(j.child_body().name())
                if a != b:
                    group[b] = a
        edges = {frozenset((root(j.parent_body().name()), root(j.child_body().name()))) for j in joints}
        links = self.robot_links()
        return {frozenset((a, b)) for i, a in enumerate(links) for b in links[i + 1:]
                if root(a) == root(b) or frozenset((root(a), root(b))) in edges}

    # -- queries
    def set_positions(self, qp: np.ndarray) -> None:
        self.plant.SetPositions(self.plant_context, qp)

    def distances(self, qp: np.ndarray, pairs: list[tuple[str, str]], max_distance: float,
                  gradients: bool = True) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """Signed distances ``d (m,)`` (m) of geometry ``pairs`` at plant positions ``qp``, their gradients
        ``(m, n_plant)`` (None without ``gradients``) and witness points ``(m, 2, 3)`` (world, m; NaN where
        culled). Pairs farther than ``max_distance`` report ``max_distance`` and a zero gradient."""
        from pydrake.multibody.tree import JacobianWrtVariable

        self.set_positions(qp)
        qo = self.scene_graph.get_query_output_port().Eval(self.sg_context)
        m = len(pairs)
        d = np.full(m, float(max_distance))
        W = np.full((m, 2, 3), np.nan)
        normals = np.zeros((m, 3))
        index = self._pair_index(pairs)
        for r in qo.ComputeSignedDistancePairwiseClosestPoints(max_distance):
            self._store(r, index, d, W, normals, max_distance)
        for k in self._filtered_pairs(pairs):
            a, b = (self.geometries[n] for n in pairs[k])
            r = qo.ComputeSignedDistancePairClosestPoints(a, b)
            self._store(r, index, d, W, normals, max_distance)
        if not gradients:
            return d, None, W
        n_p = self.plant.num_positions()
        G = np.zeros((m, n_p))
        world = self.plant.world_frame()
        jac: dict[str, tuple[np.ndarray, np.ndarray]] = {}

        def point_jacobian(body: str, p: np.ndarray) -> np.ndarray:
            if body == "world":
                return np.zeros((3, n_p))
            if body not in jac:
                frame = self.plant.GetBodyByName(body).body_frame()
                Js = self.plant.CalcJacobianSpatialVelocity(self.plant_context, JacobianWrtVariable.kQDot, frame,
                                                            np.zeros(3), world, world)
                o = frame.CalcPoseInWorld(self.plant_context).translation()
                jac[body] = (Js, o)
            Js, o = jac[body]
            r = p - o
            return Js[3:] - np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]]) @ Js[:3]

        for k in np.flatnonzero(np.isfinite(W[:, 0, 0])):
            a, b = pairs[k]
            G[k] = normals[k] @ (point_jacobian(self.body_of[a], W[k, 0]) - point_jacobian(self.body_of[b], W[k, 1]))
        return d, G, W

    def _pair_index(self, pairs) -> dict:
        key = tuple(pairs)
        cached = getattr(self, "_index_cache", None)
        if cached is not None and cached[0] == key:
            return cached[1]
        index = {}
        for k, (a, b) in enumerate(pairs):
            ga, gb = self.geometries[a], self.geometries[b]
            index[(ga, gb)] = (k, False)
            index[(gb, ga)] = (k, True)
        self._index_cache = (key, index)
        return index

    def _filtered_pairs(self, pairs) -> list[int]:
        key = tuple(pairs)
        cached = getattr(self, "_filtered_cache", None)
        if cached is not None and cached[0] == key:
            return cached[1]
        out = [k for k, (a, b) in enumerate(pairs)
               if self.inspector.CollisionFiltered(self.geometries[a], self.geometries[b])
               or (self.body_of[a] == "world" and self.body_of[b] == "world")]
        self._filtered_cache = (key, out)
        return out

    def _store(self, r, index, d, W, normals, max_distance) -> None:
        hit = index.get((r.id_A, r.id_B))
        if hit is None or r.distance > max_distance:
            return
        k, swapped = hit
        wa, wb = self._to_world(r.id_A, r.p_ACa), self._to_world(r.id_B, r.p_BCb)
        n = np.asarray(r.nhat_BA_W)
        d[k] = r.distance
        if swapped:
            W[k] = (wb, wa)
            normals[k] = -n
        else:
            W[k] = (wa, wb)
            normals[k] = n

    def _to_world(self, gid, p_G: np.ndarray) -> np.ndarray:
        """A point ``p_G (3,)`` of geometry ``gid``'s frame in the world (m) at the current positions."""
        X_WG = self.scene_graph.get_query_output_port().Eval(self.sg_context).GetPoseInWorld(gid)
        return X_WG.rotation().matrix() @ p_G + X_WG.translation()


# ------------------------------------------------------------------ pairs of a collision term
def resolve_pairs(world: CollisionWorld, pairs, groups: dict, self_collision: bool, allow, where: str
                  ) -> list[tuple[str, str]]:
    """Geometry pairs of a collision term: ``pairs`` of ``[robot side, scene side]`` names, where a robot
    side is a link, a group of ``groups`` or ``"robot"`` (every link with collision geometry) and a scene
    side an object or ``"scene"`` (every object); ``self_collision``: every two links' geometries but
    those of links a joint connects and the ``allow`` list's pairs of links."""
    links, objects = world.robot_links(), world.scene_objects()

    def robot_side(name: str) -> list[str]:
        from raico.plants.model_file import closest_names

        if name == "robot":
            return links
        if name in groups:
            return [ln for g in groups[name] for ln in robot_side(g)]
        if name in links:
            return [name]
        if world.plant.HasBodyNamed(name):
            raise ValueError(f"{where}: link '{name}' has no collision geometry: links with some are "
                             f"{closest_names(name, links)}")
        raise ValueError(f"{where}: unknown link or group '{name}': closest {closest_names(name, links + list(groups))}")

    def scene_side(name: str) -> list[str]:
        from raico.plants.model_file import closest_names

        if name == "scene":
            return objects
        if name in objects:
            return [name]
        raise ValueError(f"{where}: unknown scene object '{name}': closest {closest_names(name, objects or ['(none)'])}")

    out: list[tuple[str, str]] = []
    for p in pairs:
        for link in robot_side(p[0]):
            for obj in scene_side(p[1]):
                out.extend((a, b) for a in world.link_geometries(link) for b in world.object_geometries(obj))
    if self_collision:
        skip = world.adjacent() | {frozenset(a) for a in allow}
        for i, la in enumerate(links):
            for lb in links[i + 1:]:
                if frozenset((la, lb)) in skip:
                    continue
                out.extend((a, b) for a in world.link_geometries(la) for b in world.link_geometries(lb))
    return list(dict.fromkeys(out))


def srdf_allowed(srdf: str | Path) -> list[list[str]]:
    """The ``<disable_collisions link1 link2>`` pairs of an SRDF file."""
    try:
        root = ET.parse(srdf).getroot()
    except (OSError, ET.ParseError) as e:
        raise ValueError(f"SRDF {srdf}: cannot be read ({e})") from None
    return [[e.get("link1"), e.get("link2")] for e in root.iter("disable_collisions")]


# ------------------------------------------------------------------ the task map
class SignedDistances:
    """Signed distances of geometry pairs as a task map on planning coordinates: ``phi(q) (m,)`` (m), the
    distances capped at ``max_distance``, and ``J (m, n_q)`` (zero rows where capped).

    A batch ``Q (K, n_q)`` first bounds every pair's distance below at every step: by the last batches'
    distances (or bounds) less ``rho |q - q_k|``, the largest (:meth:`_pair_rates`; where that settles a row,
    nothing more), then by the largest of the spheres' and capsules' around its geometries and a scene
    primitive's distance (:meth:`lower_bounds`; the frames by the robot's compiled kinematics where they build,
    else Drake's), and queries only where that bound is below the cull distance (``max_distance``, or less:
    :meth:`evaluate`): a pair with a convex mesh by ``distance.c`` (one call per batch: poses, GJK, witness
    points and gradient rows from the frames), the others by SceneGraph
    (``ComputeSignedDistancePairClosestPoints``), their witness points' Jacobians from the same kinematics."""

    def __init__(self, robot, world: CollisionWorld, pairs: list[tuple[str, str]], max_distance: float,
                 name: str = "distances"):
        self.robot, self.world, self.pairs = robot, world, list(pairs)
        self.max_distance = float(max_distance)
        self.dim = len(self.pairs)
        self.name = name
        self._kernels: Any = None
        names = list(dict.fromkeys(n for p in self.pairs for n in p))
        self._slot = {n: i for i, n in enumerate(names)}
        self._names = names
        self._radius = np.array([world.bounds[n][1] for n in names])
        self._ia = np.array([self._slot[a] for a, _ in self.pairs], int)
        self._ib = np.array([self._slot[b] for _, b in self.pairs], int)
        self._gid = [(world.geometries[a], world.geometries[b]) for a, b in self.pairs]
        self._X_BG = {}   # name -> (R, p) of the geometry in its body's frame
        for n in names:   # a world file's geometry: its pose in the world (its body is welded there)
            X = world.fixed_pose.get(n) or world.inspector.GetPoseInFrame(world.geometries[n])
            self._X_BG[n] = (X.rotation().matrix(), X.translation())
        self._bodies = list(dict.fromkeys(world.body_of[n] for n in names if world.body_of[n] != "world"))
        self._R_BG = np.array([self._X_BG[n][0] for n in names]).reshape(-1, 3, 3)
        self._p_BG = np.array([self._X_BG[n][1] for n in names]).reshape(-1, 3)
        self._body_index = np.array([self._bodies.index(world.body_of[n]) if world.body_of[n] != "world"
                                     else len(self._bodies) for n in names], int)
        self._against_scene = [(p, (a, b)) for p, (a, b) in enumerate(self.pairs)
                               if world.body_of[a] != "world" and b in world.shapes_by_name
                               and world.body_of[b] == "world" and world.shapes_by_name[b].kind != "convex"]
        self._cap_ends = np.array([world.capsules[n][:2] for n in names]).reshape(-1, 2, 3)   # in the bodies' frames
        self._cap_radius = np.array([world.capsules[n][2] for n in names])
        self._scene_objects = {b: [(p, self._slot[a]) for p, (a, bb) in self._against_scene if bb == b]
                               for b in dict.fromkeys(b for _, (_, b) in self._against_scene)}
        self._rate = self._pair_rates()
        self._pair_body = np.zeros((self.dim, len(self._bodies)))   # pair p moves with body i: 1
        for p, (a, b) in enumerate(self.pairs):
            for g in (a, b):
                if world.body_of[g] != "world":
                    self._pair_body[p, self._bodies.index(world.body_of[g])] = 1.0
        self._gbody: dict = {}   # the frames' bodies -> each geometry's column in them (-1: the world)
        self._known: list | None = None   # (Qp, lower bounds) of the last batches, the newest first (None: none)
        shapes = [world.shapes_by_name.get(n) for n in names]
        known = np.array([sh is not None and sh.kind in GJK_KINDS for sh in shapes])
        convex = np.array([sh is not None and sh.kind == "convex" for sh in shapes])
        # a pair with a convex mesh (a hull of hundreds of vertices) by distance.c's GJK, the primitives' by Drake
        self._gjk_pair = known[self._ia] & known[self._ib] & (convex[self._ia] | convex[self._ib])
        self._gjk_shapes: GJKShapes | None = None
        self._hints = np.zeros((self.dim, 2), np.int64)   # per pair: where the next support searches start
        self._batches: list = []   # the last batches: (Q, cull distances, jacobians, compiled, (D, J, W))
        self.compiled = bool(self._gjk_pair.any()) and gjk_library() is not None
        self.queries = 0   # pair queries so far (a count for the timing)

    def _pair_rates(self) -> np.ndarray:
        """``rho (m, n_plant)`` (m/rad): how fast each pair's distance can change with each plant position,
        anywhere: a revolute joint that moves one geometry of the pair but not the other moves its points at
        most by their distance from the joint (bounded by the chain's offsets from the joint to the body plus
        the geometry's bounding sphere) per radian; a joint that moves both or neither, 0; other joints
        (prismatic, floating): ``inf`` (no such bound)."""
        from pydrake.multibody.tree import JointIndex

        plant = self.world.plant
        inboard: dict[str, Any] = {}
        for i in range(plant.num_joints()):
            j = plant.get_joint(JointIndex(i))
            inboard[j.child_body().name()] = j

        def offset(j) -> float:
            X_FM = j.X_FM().translation() if j.type_name() == "weld" else np.zeros(3)
            return float(np.linalg.norm(j.frame_on_child().GetFixedPoseInBodyFrame().translation())
                         + np.linalg.norm(X_FM))

        n_p = plant.num_positions()
        rho = np.zeros((self.dim, n_p))
        reach: dict[str, dict[int, float]] = {}   # geometry -> position index -> reach (m), its moving joints
        for name in self._names:
            body, (c, r) = self.world.body_of[name], self.world.bounds[name]
            out: dict[int, float] = {}
            length = float(np.linalg.norm(c)) + r
            while body != "world" and body in inboard:
                j = inboard[body]
                length += offset(j)
                if j.num_positions():
                    for k in range(j.position_start(), j.position_start() + j.num_positions()):
                        out[k] = length if j.type_name() == "revolute" else math.inf
                parent = j.parent_body()
                body = "world" if parent.index() == plant.world_body().index() else parent.name()
                length += float(np.linalg.norm(j.frame_on_parent().GetFixedPoseInBodyFrame().translation()))
            reach[name] = out
        for p, (a, b) in enumerate(self.pairs):
            ra, rb = reach[a], reach[b]
            for k in set(ra) ^ set(rb):
                rho[p, k] = ra.get(k, rb.get(k))
        return np.minimum(rho, 1e30)   # 0 * rho = 0 where a joint does not move

    def tree_kernels(self):
        """The robot's compiled tree kernels (``raico.plants.codegen.rbd``), or None where they do not build."""
        if self._kernels is None:
            from raico.plants.codegen.rbd import tree_kernels

            try:
                self._kernels = tree_kernels(self.robot)
            except NotImplementedError:
                self._kernels = False
        return self._kernels or None

    def _frames(self, Qp: np.ndarray, bodies=None, rows=None) -> dict[str, tuple[np.ndarray, ...]]:
        """Per body of the pairs (or of ``bodies``): origins ``o (K, 3)``, rotations ``R (K, 3, 3)`` (world) and the Jacobians
        of the origin ``J_o (K, 3, m)`` and of the axes' tips ``J_e (K, 3, 3, m)`` (tip i at row i) at plant
        positions ``Qp (K, m)``: a point ``p_B`` of the body is at ``o + R p_B`` with Jacobian
        ``J_o + sum_i p_B[i] (J_e[i] - J_o)`` (linear in ``p_B``). ``rows``: body -> the row indices computed
        (the others NaN; None: every row)."""
        K, m = Qp.shape
        k = self.tree_kernels()
        arrays = self._frame_arrays(Qp, bodies, rows)
        if arrays is not None:
            return self._frames_of(arrays, K, m)
        if rows is not None:
            out = {}
            for body in (self._bodies if bodies is None else bodies):
                r = rows.get(body)
                if r is not None and len(r) == K:
                    out[body] = self._frames(Qp, [body])[body]
                    continue
                part = self._frames(Qp[r], [body])[body] if r is not None and len(r) else None
                full = tuple(np.full((K, *x.shape[1:]), np.nan) for x in
                             ((np.empty((0, 3)), np.empty((0, 3, 3)), np.empty((0, 3, m)), np.empty((0, 3, 3, m)))
                              if part is None else part))
                if part is not None:
                    for f, x in zip(full, part):
                        f[r] = x
                out[body] = full
            return out
        pts = np.vstack([np.zeros(3), np.eye(3)])
        out = {}
        for body in (self._bodies if bodies is None else bodies):
            if k is not None:
                pos, Jp = k.frame_points_batch(Qp, k.tree.body(body), np.eye(3), np.zeros(3), pts)
            else:
                from pydrake.multibody.tree import JacobianWrtVariable

                w = self.world
                frame, world = w.plant.GetBodyByName(body).body_frame(), w.plant.world_frame()
                pos, Jp = np.empty((K, 4, 3)), np.empty((K, 12, m))
                for t, qp in enumerate(Qp):
                    w.set_positions(qp)
                    pos[t] = w.plant.CalcPointsPositions(w.plant_context, frame, pts.T, world).T
                    Jp[t] = w.plant.CalcJacobianTranslationalVelocity(w.plant_context, JacobianWrtVariable.kQDot,
                                                                      frame, pts.T, world, world)
            o = pos[:, 0]
            R = np.swapaxes(pos[:, 1:] - o[:, None], 1, 2)          # columns: the axes in the world
            Jp = Jp.reshape(K, 4, 3, m)
            out[body] = (o, R, Jp[:, 0], Jp[:, 1:] - Jp[:, :1])
        return out

    def _frame_arrays(self, Qp: np.ndarray, bodies=None, rows=None, row_index=None):
        """The compiled kinematics' frames (every body at once, once per row) of ``bodies`` (None: the pairs') at
        the rows of ``Qp (K, m)`` that ``rows`` (as :meth:`_frames`) asks for: the bodies' names, their origins and
        axes' tips ``(r, nb, 4, 3)``, their Jacobians ``(r, nb, 12, m)`` and ``rowmap (K,)`` (a row's index in
        them, -1: not computed; ``row_index``: the rows instead of ``rows``); None where the kernels do not build."""
        k = self.tree_kernels()
        if k is None or not hasattr(k, "body_frames_batch"):
            return None
        K = len(Qp)
        names = list(self._bodies if bodies is None else bodies)
        if row_index is not None:
            r = np.asarray(row_index, int)
        elif rows is None:
            r = np.arange(K)
        else:
            mask = np.zeros(K, bool)
            for b in names:
                mask[rows.get(b, np.zeros(0, int))] = True
            r = np.flatnonzero(mask)
        pos, Jp = k.body_frames_batch(Qp[r], [k.tree.body(b) for b in names])
        rowmap = np.full(K, -1, np.int64)
        rowmap[r] = np.arange(len(r))
        return names, pos, Jp, rowmap

    @staticmethod
    def _frames_of(arrays, K: int, m: int) -> dict[str, tuple[np.ndarray, ...]]:
        """:meth:`_frames`' dictionary of :meth:`_frame_arrays` (rows not computed: NaN)."""
        names, pos, Jp, rowmap = arrays
        r = np.flatnonzero(rowmap >= 0)
        if len(r) < K:
            full_pos, full_J = np.full((K, *pos.shape[1:]), np.nan), np.full((K, *Jp.shape[1:]), np.nan)
            full_pos[r], full_J[r] = pos, Jp
            pos, Jp = full_pos, full_J
        o = pos[:, :, 0]
        R = np.swapaxes(pos[:, :, 1:] - o[:, :, None], 2, 3)    # columns: the axes in the world
        Jp = Jp.reshape(K, len(names), 4, 3, m)
        Je = Jp[:, :, 1:] - Jp[:, :, :1]
        return {b: (o[:, i], R[:, i], Jp[:, i, 0], Je[:, i]) for i, b in enumerate(names)}

    @staticmethod
    def _arrays_of(frames: dict, K: int, m: int):
        """:meth:`_frame_arrays`' form of a :meth:`_frames` dictionary (every row)."""
        names = list(frames)
        pos, Jp = np.empty((K, len(names), 4, 3)), np.empty((K, len(names), 4, 3, m))
        for i, b in enumerate(names):
            o, R, Jo, Je = frames[b]
            pos[:, i, 0], pos[:, i, 1:] = o, o[:, None] + np.swapaxes(R, 1, 2)
            Jp[:, i, 0], Jp[:, i, 1:] = Jo, Jo[:, None] + Je
        return names, pos, Jp.reshape(K, len(names), 12, m), np.arange(K, dtype=np.int64)

    def _stacked(self, frames: dict, K: int, m: int) -> tuple[np.ndarray, ...]:
        """The bodies' frames of :meth:`_frames` stacked in ``_bodies`` order, the world last (origin 0, identity,
        no Jacobian): ``O (b+1, K, 3)``, ``R (b+1, K, 3, 3)``, ``J_o (b+1, K, 3, m)``, ``J_e (b+1, K, 3, 3, m)``."""
        nb = len(self._bodies)
        O, R = np.zeros((nb + 1, K, 3)), np.broadcast_to(np.eye(3), (nb + 1, K, 3, 3)).copy()
        Jo, Je = np.zeros((nb + 1, K, 3, m)), np.zeros((nb + 1, K, 3, 3, m))
        for i, body in enumerate(self._bodies):
            if body in frames:
                O[i], R[i], Jo[i], Je[i] = frames[body]
        return O, R, Jo, Je

    def evaluate(self, Q: np.ndarray, jacobians: bool = True, cull=None):
        """Distances ``(K, m)`` (capped), Jacobians ``(K, m, n_q)`` (None without ``jacobians``) and witness
        points ``(K, m, 2, 3)`` (world, m; NaN where not queried) at the rows of ``Q (K, n_q)``; rows with
        a non-finite ``q`` give NaN.

        ``cull`` (m; a number or ``(K, m)``, at most ``max_distance``; None: ``max_distance``): a pair whose
        lower bound reaches it is not queried and reports ``max_distance`` (a hinge ``max(0, c - d)`` with
        ``c <= cull`` needs no more: its value and gradient are exact). The last batches are kept: the same
        ``Q`` again at cull distances no larger gives the kept results (copies; a pair culled now may then
        report its distance, which the hinge reads alike)."""
        Q = np.atleast_2d(Q)
        K, m = len(Q), self.dim
        ask = np.broadcast_to(self.max_distance if cull is None else np.minimum(cull, self.max_distance), (K, m))
        for Qc, lc, jc, cc, out in self._batches:
            if jc >= jacobians and cc == self.compiled and Qc.shape == Q.shape and np.array_equal(Qc, Q) and np.all(ask <= lc):
                return out[0].copy(), (out[1].copy() if jacobians else None), out[2].copy()
        out = self._evaluate(Q, jacobians, cull)
        self._batches = [(np.array(Q), np.array(ask), jacobians, self.compiled, out), *self._batches[:BATCHES_KEPT - 1]]
        return out[0].copy(), (out[1].copy() if jacobians else None), out[2].copy()

    def _evaluate(self, Q: np.ndarray, jacobians: bool, cull):
        """:meth:`evaluate` without the kept batches."""
        P = self.robot.P
        K, m = len(Q), self.dim
        finite = np.all(np.isfinite(Q), axis=1)
        ok = np.flatnonzero(finite)
        D = np.full((K, m), self.max_distance)
        J = np.zeros((K, m, Q.shape[1])) if jacobians else None
        W = np.full((K, m, 2, 3), np.nan)
        if ok.size < K:   # rows with a non-finite q: NaN
            D[~finite] = np.nan
            if J is not None:
                J[~finite] = np.nan
        if ok.size == 0 or m == 0:
            D[:] = np.nan
            return D, (None if J is None else np.full_like(J, np.nan)), W
        Q_all = Q[ok] @ P.T
        limit = np.broadcast_to(self.max_distance if cull is None else np.minimum(cull, self.max_distance), (K, m))
        moved_lb = None
        for Qk, lbk in self._known or []:   # the last batches' bounds, moved since: the largest
            if Qk.shape == (K, Q_all.shape[1]):
                with np.errstate(invalid="ignore", over="ignore"):   # no bound (inf): a huge one
                    b = ((lbk - np.abs(Q_all - Qk) @ self._rate.T) if ok.size == K
                         else lbk[ok] - np.abs(Q_all - Qk[ok]) @ self._rate.T)
                moved_lb = b if moved_lb is None else np.fmax(moved_lb, b)
        # the rows where some pair may come within the limit: their frames, their geometric bounds, their queries
        S = (np.arange(len(ok)) if moved_lb is None
             else np.flatnonzero(~np.all(moved_lb >= limit[ok], axis=1)))
        sub, Qp = ok[S], Q_all[S]
        kept: dict = {"args": (None, None)}   # the frames' bodies and rows, their arrays, their dictionary

        def frames_of():   # the dictionary where asked (the compiled queries read the arrays)
            if "frames" not in kept:
                a = kept.get("arrays")
                kept["frames"] = self._frames(Qp, *kept["args"]) if a is None else self._frames_of(a, *Qp.shape)
            return kept["frames"]

        if moved_lb is None:
            kept["arrays"] = self._frame_arrays(Qp)
            lb = self.lower_bounds(frames_of(), len(S))
        else:   # and of those, the pairs that may: their bodies' frames there and their geometric bounds
            need = ~(moved_lb[S] >= limit[sub])
            cols = np.flatnonzero(need.any(axis=0))
            at = need[:, cols].astype(float) @ self._pair_body[cols]   # (rows, bodies): pairs needing the body
            bodies = [b for i, b in enumerate(self._bodies) if at[:, i].any()]
            kept["arrays"] = self._frame_arrays(Qp, bodies, row_index=np.flatnonzero(at.any(axis=1)))
            if kept["arrays"] is None:
                kept["args"] = (bodies, {b: np.flatnonzero(at[:, i]) for i, b in enumerate(self._bodies) if b in bodies})
            lb = moved_lb[S].copy()
            # a pair GJK measures is queried where the motion bound does not settle it (a geometric bound
            # costs about what its query does); the others' geometric bounds first
            geo = cols[~self._gjk_pair[cols]] if self.compiled else cols
            if geo.size:
                with np.errstate(invalid="ignore"):
                    lb[:, geo] = np.fmax(self.lower_bounds(frames_of(), len(S), geo), lb[:, geo])
        near_all = lb < limit[sub]
        tt, pp, dist, nrm, pa, pb, exact, done = self._query(near_all, Qp, frames_of, kept, limit[sub], jacobians)
        known_lb = np.full((K, m), np.nan)
        if moved_lb is not None:
            known_lb[ok] = moved_lb
        known_lb[sub] = lb
        known_lb[sub[exact[0]], exact[1]] = exact[2]
        Qk = np.full((K, Q_all.shape[1]), np.nan)
        Qk[ok] = Q_all
        self._known = [(Qk, known_lb), *(self._known or [])[:KNOWN_KEPT - 1]]
        self.queries += len(exact[2])
        if not len(tt):
            return D, J, W
        D[sub[tt], pp] = dist
        Jd = np.zeros((len(tt), Qp.shape[1])) if jacobians else None
        py = np.arange(len(tt))
        if done is not None:   # the compiled queries' witness points and gradient rows
            W[sub[tt[done[0]]], pp[done[0]]] = done[1][done[0]]
            if jacobians:
                Jd[done[0]] = done[2][done[0]]
            py = np.flatnonzero(~done[0])
        if len(py):   # Drake's: from the frames here
            O, R, Jo, Je = self._stacked(frames_of(), len(sub), Qp.shape[1])
            t2, p2, jd = tt[py], pp[py], 0.0
            for side, (slots, pts) in enumerate(((self._ia[p2], pa[py]), (self._ib[p2], pb[py]))):
                p_B = np.einsum("kij,kj->ki", self._R_BG[slots], pts) + self._p_BG[slots]   # in the body's frame
                b = self._body_index[slots]
                W[sub[t2], p2, side] = O[b, t2] + np.einsum("kij,kj->ki", R[b, t2], p_B)
                if jacobians:   # n . J(p_B), J(p_B) = J_o + sum_i p_B[i] (J_e[i] - J_o)
                    nJ = (np.einsum("kc,kcm->km", nrm[py], Jo[b, t2])
                          + np.einsum("ki,kc,kicm->km", p_B, nrm[py], Je[b, t2]))
                    jd = jd + (nJ if side == 0 else -nJ)
            if jacobians:
                Jd[py] = jd
        if jacobians:
            J[sub[tt], pp] = Jd @ P
        return D, J, W

    def _query(self, near_all: np.ndarray, Qp: np.ndarray, frames_of, kept: dict, limit: np.ndarray,
               jacobians: bool = True):
        """The pairs ``near_all (K, m)`` queried at postures ``Qp``: those with a convex mesh by :class:`GJKShapes`
        (where it converges with the cores apart; stopped where a separating plane puts them ``limit (K, m)``
        apart), the rest (and those) by Drake's ``ComputeSignedDistancePairClosestPoints``; the frames from
        ``kept["arrays"]`` (:meth:`_frame_arrays`) or ``frames_of()`` (:meth:`_frames`). Returns the pairs
        within ``max_distance`` (row, pair, distance, normal from B to A, witness points in the geometries'
        frames), every query's (rows, pairs, distances or the separating plane's lower bound) and, for the
        returned pairs, which the compiled queries finished with their world witness points ``(n, 2, 3)`` and
        gradient rows on plant positions (None without ``jacobians``); None where none were compiled."""
        w = self.world
        tq, pq = np.nonzero(near_all)
        drake, culled = np.ones(len(tq), bool), np.zeros(len(tq), bool)
        dist, nrm, pa, pb = np.full(len(tq), np.nan), np.zeros((len(tq), 3)), np.zeros((len(tq), 3)), np.zeros((len(tq), 3))
        compiled = None
        if self.compiled and len(tq):
            g = np.flatnonzero(self._gjk_pair[pq])
            if g.size:
                if self._gjk_shapes is None:
                    self._gjk_shapes = GJKShapes([w.shapes_by_name.get(n) for n in self._names])
                arrays = kept.get("arrays")
                if arrays is None:
                    arrays = self._arrays_of(frames_of(), *Qp.shape)
                names, fr, Jf, rowmap = arrays
                gbody = self._gbody.get(tuple(names))
                if gbody is None:
                    col = {b: i for i, b in enumerate(names)}
                    gbody = self._gbody[tuple(names)] = np.array(
                        [-1 if w.body_of[n] == "world" else col.get(w.body_of[n], len(names)) for n in self._names],
                        np.int64)
                d, Wc, n, Jc, status = self._gjk_shapes.frames_distances(
                    tq[g], pq[g], self._ia, self._ib, gbody, self._R_BG, self._p_BG, rowmap, fr,
                    Jf if jacobians else None, limit[tq[g], pq[g]], self._hints)
                ok = status == 0
                compiled = np.zeros(len(tq), bool), np.full((len(tq), 2, 3), np.nan), (
                    np.zeros((len(tq), Qp.shape[1])) if jacobians else None)
                done = g[ok]
                dist[done], nrm[done] = d[ok], n[ok]
                compiled[0][done], compiled[1][done] = True, Wc[ok]
                if jacobians:
                    compiled[2][done] = Jc[ok]
                dist[g[status == 3]] = d[status == 3]
                culled[g[status == 3]] = True
                drake[g[ok | (status == 3)]] = False
        handed, last = np.flatnonzero(drake), -1
        port = w.scene_graph.get_query_output_port() if handed.size else None
        for i in handed:
            t = tq[i]
            if t != last:
                w.set_positions(Qp[t])
                qo, last = port.Eval(w.sg_context), t
            r = qo.ComputeSignedDistancePairClosestPoints(*self._gid[pq[i]])
            dist[i], nrm[i], pa[i], pb[i] = r.distance, r.nhat_BA_W, r.p_ACa, r.p_BCb
        live = (dist < self.max_distance) & ~culled
        done_live = None if compiled is None else tuple(None if x is None else x[live] for x in compiled)
        return tq[live], pq[live], dist[live], nrm[live], pa[live], pb[live], (tq, pq, dist), done_live

    def lower_bounds(self, frames: dict, K: int, cols=None) -> np.ndarray:
        """Lower bounds ``(K, m)`` (m) of the pairs' distances (of pairs ``cols`` only: ``(K, len(cols))``) at the ``K``
        postures of ``frames`` (:meth:`_frames`, the pairs' bodies at least):
        the largest of the bounding spheres', the bounding capsules' (segment distance less both radii) and,
        for a robot geometry against a scene primitive, the primitive's distance to its sphere less its radius."""
        w, n = self.world, len(self._names)
        cols = np.arange(self.dim) if cols is None else np.asarray(cols, int)
        ia, ib = self._ia[cols], self._ib[cols]
        C, E = np.full((K, n, 3), np.nan), np.full((K, n, 2, 3), np.nan)
        for i in np.union1d(ia, ib):
            name = self._names[i]
            c, body, ends = w.bounds[name][0], w.body_of[name], self._cap_ends[i]
            if body == "world":
                C[:, i], E[:, i] = c, ends
            else:
                o, R = frames[body][0], frames[body][1]
                C[:, i] = o + R @ c
                E[:, i] = o[:, None] + np.einsum("kij,ej->kei", R, ends)
        with np.errstate(invalid="ignore"):
            lb = np.linalg.norm(C[:, ia] - C[:, ib], axis=2) - self._radius[ia] - self._radius[ib]
            caps = (segment_distances(E[:, ia, 0], E[:, ia, 1], E[:, ib, 0], E[:, ib, 1])
                    - self._cap_radius[ia] - self._cap_radius[ib])
        lb = np.fmax(lb, np.nan_to_num(caps, nan=-np.inf))
        col_of = {int(p): j for j, p in enumerate(cols)}
        for b, rows in self._scene_objects.items():   # a robot geometry's sphere against a scene primitive
            rows = [r for r in rows if r[0] in col_of]
            if not rows:
                continue
            p, slots = np.array([col_of[r[0]] for r in rows]), np.array([r[1] for r in rows])
            d = point_distance(w.shapes_by_name[b], C[:, slots].reshape(-1, 3)).reshape(K, -1) - self._radius[slots]
            lb[:, p] = np.maximum(lb[:, p], d)
        return lb - 1e-9   # rounding: a bound never above the distance

    def value_and_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        D, J, _ = self.evaluate(q[None])
        return D[0], J[0]

    def values_and_jacobians(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        D, J, _ = self.evaluate(Q)
        return D, J

    def value(self, q: np.ndarray) -> np.ndarray:
        return self.evaluate(q[None], jacobians=False)[0][0]

    def witnesses(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distances ``(m,)`` (capped) and witness points ``(m, 2, 3)`` (world, m; NaN where capped) at ``q``."""
        D, _, W = self.evaluate(q[None], jacobians=False)
        return D[0], W[0]
