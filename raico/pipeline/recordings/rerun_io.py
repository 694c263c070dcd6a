"""Rerun recordings of stage runs.

One ``.rrd`` per stage run, written by :class:`Recording` (its own ``rr.RecordingStream``, never the
global one, so parallel workers don't mix) with one blueprint per stage (:func:`stage_blueprint`;
generic recordings get :func:`default_blueprint`): the 3D view ``robot`` of ``world/**`` on the left
and the plots that matter on the right, on the ``sim_time`` timeline.

Entity layout::

    world/robot/<body>             Transform3D of the body in the world, on ``sim_time``
    world/robot/<body>/<geometry>  static primitive + static pose in the body frame
    joints[/<group>]               Scalars on ``sim_time`` (rad), one series per joint, named

Timelines: ``sim_time`` (duration, s), ``iteration`` and ``episode`` (sequences). Drake quaternions
are wxyz, Rerun's xyzw; Rerun capsules start at z = 0 while Drake's are centred on their frame, so
they are shifted by -length/2 along z.

Legends stay short: a vector is one entity whose series are named, and joints are grouped by limb
where the joint names tell the limbs (:func:`joint_groups`), one plot per group; angles of continuous
joints (the pendulum's ``theta``) are unwrapped and named ``<joint> (unwrapped)``.

Decimation (:func:`pose_indices`, :func:`plot_indices`): poses at full rate while samples x bodies
<= ``POSE_BUDGET``, otherwise at most ``MAX_POSES`` per trajectory (every s-th sample, the last one
and any via-point step); scalar plots at full rate up to ``MAX_PLOT_SAMPLES`` samples, then
decimated the same way. A pose lasts until the next one on the timeline, so a decimated motion
still plays through.
"""

from __future__ import annotations

import functools
import json
import re
import sys
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Self, TypeAlias

# Rerun's Rust side logs its own (coloured) error lines to stderr, e.g. when its file writer fails;
# the raico command sets RUST_LOG=off unless the user set it (raico/pipeline/interface/cli/__init__.py); this module leaves
# RUST_LOG to its importer.
import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from pydrake.geometry import Box, Capsule, Cylinder, Ellipsoid, Mesh, Role, Sphere
from pydrake.multibody.tree import BodyIndex
from scipy.spatial.transform import Rotation

__all__ = [
    "MAX_PLOT_SAMPLES",
    "MAX_POSES",
    "POSE_BUDGET",
    "SEQUENCE_TIMELINES",
    "Recording",
    "application_id",
    "body_poses",
    "continuous_joints",
    "decimate",
    "default_blueprint",
    "entity_name",
    "group_views",
    "joint_groups",
    "log_body_trajectory",
    "log_joint_series",
    "log_path_series",
    "log_points_path",
    "log_robot_geometry",
    "log_robot_pose",
    "log_scalars",
    "n_bodies",
    "plot_indices",
    "pose_indices",
    "robot_eye",
    "rot_to_quat_xyzw",
    "stage_blueprint",
    "unwrap",
]

ROBOT_PREFIX = "world/robot"
SEQUENCE_TIMELINES = frozenset({"iteration", "episode"})
DEFAULT_COLOR = (0.7, 0.7, 0.7, 1.0)
_UNSAFE = re.compile(r"[^A-Za-z0-9_\-.]")


def entity_name(name: str) -> str:
    """A Drake name as one entity-path part: scope (``model::``) dropped, odd characters -> ``_``."""
    return _UNSAFE.sub("_", name.rsplit("::", 1)[-1]) or "_"


Eye = tuple[Sequence[float], Sequence[float]]  # (camera position, look target), m
ViewLike: TypeAlias = rrb.View | rrb.Container
ROBOT_VIEW = "robot"  # the 3D view's name in every blueprint (raico.pipeline.recordings.screenshots looks for it)
MAX_POSES = 200  # robot poses per trajectory when full rate is not cheap
POSE_BUDGET = 3000  # samples x bodies logged at full rate (about 180 kB of poses)
MAX_PLOT_SAMPLES = 2000  # samples per plotted trajectory
# distinct series colours (Tableau 10), for the joints of a group
PALETTE = ((78, 121, 167), (242, 142, 43), (225, 87, 89), (118, 183, 178), (89, 161, 79), (237, 201, 72),
           (176, 122, 161), (255, 157, 167), (156, 117, 95), (186, 176, 172))


def _robot_view(eye: Eye | None) -> rrb.Spatial3DView:
    controls = None
    if eye is not None:
        controls = rrb.EyeControls3D(position=list(map(float, eye[0])),
                                     look_target=list(map(float, eye[1])), eye_up=[0.0, 0.0, 1.0])
    return rrb.Spatial3DView(origin="/world", contents="/world/**", name=ROBOT_VIEW, eye_controls=controls)


def default_blueprint(time_series: Sequence[str] = (), eye: Eye | None = None,
                      timeline: str | None = None) -> rrb.Blueprint:
    """3D view of ``world/**`` beside time series of ``joints/**`` and of each extra root.

    ``time_series``: entity roots such as ``"task"`` or ``"cost/**"``; ``eye``: initial
    camera ``(position, look_target)`` in the world (m), see :func:`robot_eye`; ``timeline``:
    the timeline the viewer opens on (None: the viewer's choice).
    """
    roots = ["joints", *[r.strip("/").removesuffix("/**") for r in time_series if r]]
    plots = [rrb.TimeSeriesView(origin=f"/{r}", name=r) for r in dict.fromkeys(roots)]
    return stage_blueprint(eye, plots, timeline=timeline)


def stage_blueprint(
    eye: Eye | None,
    plots: Sequence[ViewLike],
    below_robot: Sequence[ViewLike] = (),
    *,
    timeline: str | None = "sim_time",
    plot_shares: Sequence[float] | None = None,
    robot_share: float = 3.0,
    play_state: str = "paused",
) -> rrb.Blueprint:
    """The ``robot`` 3D view (``eye``: its camera, see :func:`robot_eye`) above ``below_robot``
    (each 1 share against ``robot_share``) on the left (3/5 of the width), ``plots`` stacked on the
    right (``plot_shares``: their heights); the time panel collapsed on ``timeline`` (None: the
    viewer picks one; ``play_state`` "following" opens at its last time), the other panels collapsed."""
    left: ViewLike = _robot_view(eye)
    if below_robot:
        left = rrb.Vertical(left, *below_robot, row_shares=[robot_share, *[1.0] * len(below_robot)])
    parts: list[Any] = []
    if plots:
        shares = list(plot_shares) if plot_shares is not None else None
        parts.append(rrb.Horizontal(left, rrb.Vertical(*plots, row_shares=shares), column_shares=[3, 2]))
    else:
        parts.append(left)
    if timeline is not None:
        parts.append(rrb.TimePanel(state="collapsed", timeline=timeline, play_state=play_state))
    return rrb.Blueprint(*parts, collapse_panels=True)


def group_views(root: str, groups: Iterable[str], title: str | None = None) -> ViewLike:
    """Time series of ``root`` (``groups`` from :func:`joint_groups`): one view named ``title`` if it
    is not split in groups, else a tab per group, ``<title without its unit>: <group>``."""
    title = title or root
    names = [g for g in groups if g]
    if not names:
        return rrb.TimeSeriesView(origin=f"/{root}", name=title)
    short = title.split(" (")[0]
    return rrb.Tabs(*[rrb.TimeSeriesView(origin=f"/{root}/{g}", name=f"{short}: {g}") for g in names],
                    name=title, active_tab=0)


def application_id(stage: str, *parts: Any) -> str:
    """The application id of a stage's recording, e.g. ``raico-plan-nao-balance``: one per layout.

    A Rerun viewer keeps one active blueprint per application id for all its recordings: with one
    id for every recording, a plan of the Nao opened after one of the arm would show the arm's
    views (and Rerun 0.41 does not switch to a file's own blueprint on opening it, even one sent as
    active). The stage, the plant and the task fix the views, so they name the application."""
    return "-".join(entity_name(str(x)) for x in ("raico", stage, *parts) if x not in (None, ""))


def _property_value(value: Any) -> Any:
    """A config value as something ``rr.AnyValues`` takes (nested values become JSON text)."""
    if isinstance(value, bool | int | float | str):
        return value
    return json.dumps(value, sort_keys=True, default=str)


class Recording:
    """A Rerun recording saved to ``path`` (context manager; ``.rec`` is the stream).

    ``application_id``: see :func:`application_id`; ``name``: recording name shown in the viewer;
    ``blueprint``: the layout the file opens with
    (default: :func:`default_blueprint` of ``time_series``, extra plot roots, and ``eye``, the
    initial camera).

    ``properties`` (the run's config, key, ...) become recording properties under
    ``raico``, plus the whole dict as JSON text in ``raico_json``. An unset (None) option is
    left out of ``raico`` (it stays in the JSON): Rerun types a property name by its first
    value in a process, so ``"null"`` text there would make a later run's number fail to convert.
    """

    def __init__(
        self,
        path: str | Path,
        application_id: str = "raico",
        properties: Mapping[str, Any] | None = None,
        *,
        name: str | None = None,
        time_series: Sequence[str] = (),
        eye: Eye | None = None,
        recording_id: str | None = None,
        blueprint: rrb.Blueprint | None = None,
    ) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.rec = rr.RecordingStream(application_id, recording_id=recording_id)
        # Recorded into memory and written to the file by Python at close: Rerun's own file writer
        # hangs in flush/disconnect on and off when its writes fail (EFBIG, ENOSPC; rerun 0.41),
        # while a Python write fails at once with the OSError that names the cause.
        self._mem = self.rec.memory_recording()
        # active as well as default: a viewer keeps one active blueprint per application id, which a
        # default blueprint does not replace (see application_id)
        self.rec.send_blueprint(default_blueprint(time_series, eye) if blueprint is None else blueprint,
                                make_active=True, make_default=True)
        self.properties = dict(properties or {})
        if name is not None:
            self.rec.send_recording_name(name)
        if self.properties:
            values = {str(k): _property_value(v) for k, v in self.properties.items() if v is not None}
            self.rec.send_property("raico", rr.AnyValues(**values))
            blob = json.dumps(self.properties, sort_keys=True, default=str)
            self.rec.send_property("raico_json", rr.AnyValues(json=blob))
        # Z up, as in Drake
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self._closed = False

    def close(self) -> None:
        """Flush everything and write the file (idempotent). ``OSError`` naming the file if it
        cannot be written (full disk, file size limit, ...); a partial file is removed."""
        if not self._closed:
            self._closed = True
            self.rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
            # the stream as recorded; what the memory sink adds on disconnect is a second stream
            # (its own header, an empty footer), which readers would take for a damaged file
            data = self._mem.drain_as_bytes()
            self.rec.disconnect()
            try:
                with open(self.path, "wb") as f:
                    f.write(data)
            except OSError as e:
                self.path.unlink(missing_ok=True)
                raise OSError(e.errno, e.strerror, str(self.path)) from None

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
            return
        try:  # already failing: that error is the one to report
            self.close()
        except OSError:
            pass


FLUSH_TIMEOUT_S = 600.0  # a flush into memory ends as soon as every message is encoded


def _stream(rec: Recording | rr.RecordingStream) -> rr.RecordingStream:
    return rec.rec if isinstance(rec, Recording) else rec


# ---------------------------------------------------------------- robot geometry


def _rgba(props: Any) -> np.ndarray:
    """Illustration ("phong", "diffuse") colour as uint8 RGBA (grey if missing)."""
    rgba = DEFAULT_COLOR
    if props is not None and props.HasProperty("phong", "diffuse"):
        rgba = props.GetProperty("phong", "diffuse").rgba
    return np.round(np.clip(np.asarray(rgba, dtype=float), 0.0, 1.0) * 255).astype(np.uint8)


def _primitive(shape: Any, color: np.ndarray) -> Any | None:
    """A Drake shape as a solid Rerun archetype in the geometry frame (None if unsupported)."""
    kw = {"colors": [color], "fill_mode": "solid"}
    if isinstance(shape, Box):
        return rr.Boxes3D(sizes=[[shape.width(), shape.depth(), shape.height()]], **kw)
    if isinstance(shape, Sphere):
        return rr.Ellipsoids3D(radii=[shape.radius()], **kw)
    if isinstance(shape, Ellipsoid):
        return rr.Ellipsoids3D(half_sizes=[[shape.a(), shape.b(), shape.c()]], **kw)
    if isinstance(shape, Capsule):  # Rerun: from z = 0 to z = length; Drake: centred
        length = shape.length()
        return rr.Capsules3D(lengths=[length], radii=[shape.radius()],
                             translations=[[0.0, 0.0, -length / 2]], **kw)
    if isinstance(shape, Cylinder):  # centred in both
        return rr.Cylinders3D(lengths=[shape.length()], radii=[shape.radius()], **kw)
    if isinstance(shape, Mesh):
        return _mesh(shape, color)
    return None


MESH_FACES_MAX = 20000  # triangles per visual mesh in a recording (finer meshes decimated by face sampling)


def _mesh(shape: Any, color: np.ndarray) -> Any | None:
    """A visual mesh as ``Mesh3D`` (any format trimesh reads: STL, OBJ, COLLADA ``.dae`` that Rerun
    cannot read), scaled as the model says; None (with one line on stderr) if it cannot be read."""
    path = Path(str(shape.source().path())) if shape.source().is_path() else None
    if path is None:
        return None
    mesh = _read_mesh(str(path))
    if mesh is None:
        return None
    vertices, normals, faces = mesh
    scale = np.asarray(shape.scale3(), float)
    normals = normals / scale  # normals of a scaled mesh: the inverse-transpose of the scaling
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    return rr.Mesh3D(vertex_positions=vertices * scale, vertex_normals=normals, triangle_indices=faces,
                     albedo_factor=_visible(color))


def _visible(color: np.ndarray) -> np.ndarray:
    """A colour lifted to at least a dark grey (a black part vanishes against the viewer's black)."""
    rgb = np.asarray(color[:3], float)
    lift = max(0.0, 70.0 - float(rgb.max()))
    return np.concatenate([np.minimum(rgb + lift, 255.0), np.asarray(color[3:4], float)]).astype(np.uint8)


def _collada_y_up(path: str) -> bool:
    with open(path, "rb") as f:
        head = f.read(4096)
    return b"<up_axis>Y_UP</up_axis>" in head


@functools.cache
def _read_mesh(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Vertices ``(V, 3)``, vertex normals ``(V, 3)`` and triangles ``(F, 3)`` of a mesh file."""
    import logging

    import trimesh

    logging.getLogger("trimesh").setLevel(logging.ERROR)
    try:
        m = trimesh.load(path, force="mesh", process=False)
        vertices, faces = np.asarray(m.vertices, np.float32), np.asarray(m.faces, np.uint32)
        normals = np.asarray(m.vertex_normals, np.float32)
        if path.lower().endswith(".dae") and _collada_y_up(path):  # COLLADA's Y_UP, as assimp reads it: z up
            flip = np.array([1, -1, 1], np.float32)   # float32 kept: what Rerun stores
            vertices, normals = vertices[:, [0, 2, 1]] * flip, normals[:, [0, 2, 1]] * flip
    except Exception as e:  # noqa: BLE001 - any reader failure: the visual is skipped, said once
        print(f"raico: note: visual mesh {Path(path).name} cannot be read ({type(e).__name__}): not drawn",
              file=sys.stderr)
        return None
    if faces.size == 0:
        print(f"raico: note: visual mesh {Path(path).name} has no triangles: not drawn", file=sys.stderr)
        return None
    if len(faces) > MESH_FACES_MAX:
        faces = faces[np.linspace(0, len(faces) - 1, MESH_FACES_MAX).astype(int)]
    return vertices, normals, faces


def _bodies(plant: Any) -> list[Any]:
    return [plant.get_body(BodyIndex(i)) for i in range(plant.num_bodies())]


def log_robot_geometry(
    rec: Recording | rr.RecordingStream, robot: Any, prefix: str = ROBOT_PREFIX
) -> dict[str, list[str]]:
    """Log every illustration geometry as a static primitive under ``prefix/<body>/<geometry>``.

    Each geometry gets a static Transform3D: its pose in the body frame (m, xyzw).
    Returns ``{body entity name: [geometry entity names]}`` (bodies with geometry only).
    Meshes are drawn as triangle meshes (``_mesh``); half spaces are skipped.
    """
    stream, plant = _stream(rec), robot.plant
    inspector = robot.scene_graph.model_inspector()
    logged: dict[str, list[str]] = {}
    for body in _bodies(plant):
        frame_id = plant.GetBodyFrameIdIfExists(body.index())
        if frame_id is None:
            continue
        bname = entity_name(body.name())
        for gid in inspector.GetGeometries(frame_id, Role.kIllustration):
            color = _rgba(inspector.GetIllustrationProperties(gid))
            archetype = _primitive(inspector.GetShape(gid), color)
            if archetype is None:
                continue
            gname = entity_name(inspector.GetName(gid))
            X_BG = inspector.GetPoseInFrame(gid)
            path = f"{prefix}/{bname}/{gname}"
            stream.log(path, rr.Transform3D(translation=X_BG.translation(),
                                            quaternion=_wxyz_to_xyzw(X_BG.rotation().ToQuaternion().wxyz())),
                       archetype, static=True)
            logged.setdefault(bname, []).append(gname)
    return logged


def _wxyz_to_xyzw(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


# ---------------------------------------------------------------- trajectories


def rot_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` -> unit quaternions ``(..., 4)`` xyzw with w >= 0."""
    R = np.asarray(R, dtype=float)
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat(canonical=True)  # scipy: xyzw
    return q.reshape(*R.shape[:-2], 4)


def body_poses(robot: Any, Q: np.ndarray) -> tuple[list[str], np.ndarray, np.ndarray]:
    """World poses of every body but the world at each sample of planning ``Q (K, n_q)`` (rad).

    Returns ``(body names, translations (K, B, 3) m, quaternions (K, B, 4) xyzw)``.
    """
    plant = robot.plant
    ctx = plant.CreateDefaultContext()
    bodies = [b for b in _bodies(plant) if b.index() != plant.world_body().index()]
    idx = [int(b.index()) for b in bodies]
    port = plant.get_body_poses_output_port()
    Qp = robot.to_plant_q(np.atleast_2d(np.asarray(Q, dtype=float)))
    M = np.empty((len(Qp), len(bodies), 3, 4))
    for k, qp in enumerate(Qp):
        plant.SetPositions(ctx, qp)
        poses = port.Eval(ctx)
        for j, i in enumerate(idx):
            M[k, j] = poses[i].GetAsMatrix34()
    return [b.name() for b in bodies], M[..., 3], rot_to_quat_xyzw(M[..., :3])


def robot_eye(robot: Any, q: np.ndarray | None = None) -> Eye:
    """A front-right, slightly raised camera ``(position, look_target)`` (m) framing the
    robot's bodies at planning ``q (n_q,)`` (default posture if None), or at every row of
    ``q (K, n_q)`` (a motion: the camera frames 20 of its samples; rows that are not finite are
    left out)."""
    Q = np.atleast_2d(np.asarray(robot.default_q if q is None else q, dtype=float))
    Q = Q[np.all(np.isfinite(Q), axis=1)]
    if not len(Q):
        Q = np.atleast_2d(robot.default_q)
    _, T, _ = body_poses(robot, Q[decimate(len(Q), 20)])
    lo, hi = T.min(axis=(0, 1)), T.max(axis=(0, 1))
    target = (lo + hi) / 2
    size = max(float(np.linalg.norm(hi - lo)), 0.3)
    direction = np.array([1.0, -0.75, 0.45])
    return target + 1.25 * size * direction / np.linalg.norm(direction), target


# ---------------------------------------------------------------- decimation


def decimate(K: int, max_samples: int, keep: Iterable[int] = ()) -> np.ndarray:
    """Sorted indices of about ``max_samples`` of ``K`` samples: every s-th one from the first
    (``s = ceil((K - 1) / (max_samples - 1))``), the last one and the indices in ``keep``
    (via-point steps); every index if ``K <= max_samples``."""
    if K <= max_samples:
        return np.arange(K)
    stride = -(-(K - 1) // max(max_samples - 1, 1))
    idx = np.r_[np.arange(0, K, stride), K - 1, [k for k in keep if 0 <= k < K]]
    return np.unique(idx.astype(np.int64))


def pose_indices(K: int, n_bodies: int, keep: Iterable[int] = ()) -> np.ndarray:
    """Samples of a ``K``-sample motion whose robot poses are logged: all of them while
    ``K * n_bodies <= POSE_BUDGET``, else at most about ``MAX_POSES`` (:func:`decimate`)."""
    if K * n_bodies <= POSE_BUDGET:
        return np.arange(K)
    return decimate(K, MAX_POSES, keep)


def plot_indices(K: int, keep: Iterable[int] = ()) -> np.ndarray:
    """Samples of a ``K``-sample trajectory that are plotted: all up to ``MAX_PLOT_SAMPLES``."""
    return decimate(K, MAX_PLOT_SAMPLES, keep)


def _time_column(timeline: str, times: np.ndarray) -> rr.TimeColumn:
    """``sim_time`` and other float timelines as durations (s); ``iteration``/``episode``/ints as sequences."""
    t = np.asarray(times)
    if timeline in SEQUENCE_TIMELINES or np.issubdtype(t.dtype, np.integer):
        return rr.TimeColumn(timeline, sequence=t.astype(np.int64))
    return rr.TimeColumn(timeline, duration=t.astype(np.float64))


def n_bodies(robot: Any) -> int:
    """Bodies of the robot but the world (each gets a pose)."""
    return robot.plant.num_bodies() - 1


def log_body_trajectory(
    rec: Recording | rr.RecordingStream,
    robot: Any,
    times: np.ndarray,
    Q: np.ndarray,
    prefix: str = ROBOT_PREFIX,
    timeline: str = "sim_time",
    joints: bool = True,
    poses: np.ndarray | None = None,
    keep: Iterable[int] = (),
) -> list[str]:
    """Log body world poses for ``times (K,)`` s and ``Q (K, n_q)`` rad with ``send_columns``.

    ``prefix/<body>`` gets Transform3D columns (translation m, quaternion xyzw) at the samples
    ``poses`` (default :func:`pose_indices`, ``keep``: samples to include, e.g. via-points);
    with ``joints`` also the joint angles (:func:`log_joint_series`, at :func:`plot_indices`).
    Returns the body entity names.
    """
    stream = _stream(rec)
    Q = np.atleast_2d(np.asarray(Q, dtype=float))
    times = np.asarray(times, dtype=float)
    if len(times) != len(Q):
        raise ValueError(f"times has {len(times)} samples but Q has {len(Q)}")
    keep = list(keep)
    idx = pose_indices(len(Q), n_bodies(robot), keep) if poses is None else np.asarray(poses, dtype=np.int64)
    names, T, R = body_poses(robot, Q[idx])
    index = [_time_column(timeline, times[idx])]
    entities = [entity_name(n) for n in names]
    for j, ent in enumerate(entities):
        stream.send_columns(f"{prefix}/{ent}", indexes=index,
                            columns=rr.Transform3D.columns(translation=T[:, j], quaternion=R[:, j]))
    if joints:
        sel = plot_indices(len(Q), keep)
        log_joint_series(stream, robot.joint_names, times[sel], Q[sel], timeline=timeline,
                         continuous=continuous_joints(robot))
    return entities


def log_robot_pose(
    rec: Recording | rr.RecordingStream,
    robot: Any,
    q: np.ndarray,
    timeline: str,
    time: float | int | np.ndarray,
    prefix: str = ROBOT_PREFIX,
) -> None:
    """The robot at planning ``q (n_q,)`` from ``time`` on ``timeline`` (one Transform3D per body),
    or at each row of ``q (K, n_q)`` from the matching ``time (K,)``: poses on a timeline that has
    no motion of its own (a plan's ``iteration``, the learn loop's ``episode``), where the bodies
    would otherwise sit at the world origin."""
    stream = _stream(rec)
    Q = np.atleast_2d(np.asarray(q, dtype=float))
    times = np.atleast_1d(np.asarray(time))
    if len(times) != len(Q):
        raise ValueError(f"{len(times)} times but {len(Q)} poses")
    names, T, R = body_poses(robot, Q)
    index = [_time_column(timeline, times)]
    for j, n in enumerate(names):
        stream.send_columns(f"{prefix}/{entity_name(n)}", indexes=index,
                            columns=rr.Transform3D.columns(translation=T[:, j], quaternion=R[:, j]))


# ---------------------------------------------------------------- joints

_LIMBS = (
    ("head", re.compile(r"^(Head|Neck)")),
    ("left_arm", re.compile(r"^L(Shoulder|Elbow|Wrist|Hand)")),
    ("right_arm", re.compile(r"^R(Shoulder|Elbow|Wrist|Hand)")),
    ("left_leg", re.compile(r"^L(Hip|Knee|Ankle)")),
    ("right_leg", re.compile(r"^R(Hip|Knee|Ankle)")),
)


def joint_groups(joint_names: Sequence[str]) -> dict[str, list[int]]:
    """Joint indices by limb, from the names (the Nao's ``LShoulderPitch`` -> ``left_arm``, ...;
    limbs ``head``, ``left_arm``, ``right_arm``, ``left_leg``, ``right_leg``, in that order, those
    with joints). ``{"": all}`` (no groups) unless every name tells its limb."""
    groups: dict[str, list[int]] = {}
    for j, name in enumerate(joint_names):
        limb = next((g for g, pattern in _LIMBS if pattern.match(name)), None)
        if limb is None:
            return {"": list(range(len(joint_names)))}
        groups.setdefault(limb, []).append(j)
    return {g: groups[g] for g, _ in _LIMBS if g in groups}


def continuous_joints(robot: Any) -> np.ndarray:
    """``(n_q,)`` bool: joints whose range exceeds a full turn (no effective limit: their angle
    may wind, e.g. the pendulum's ``theta``); their plots are unwrapped."""
    span = np.asarray(robot.upper, dtype=float) - np.asarray(robot.lower, dtype=float)
    return ~(span <= 2 * np.pi + 1e-9)


def log_joint_series(
    rec: Recording | rr.RecordingStream,
    joint_names: Sequence[str],
    times: np.ndarray,
    values: np.ndarray,
    root: str = "joints",
    timeline: str = "sim_time",
    continuous: Sequence[bool] | np.ndarray | None = None,
) -> dict[str, str]:
    """Joint series ``values (K, n)`` against ``times (K,)``: one entity per limb
    (:func:`joint_groups`), ``root/<group>``, or ``root`` itself for a robot without limbs, its
    series named after the joints. Joints flagged ``continuous (n,)`` (angles, rad) are unwrapped
    along time and named ``<joint> (unwrapped)``. Returns ``{group: entity}``."""
    values = np.atleast_2d(np.asarray(values, dtype=float)).copy()
    flags = np.zeros(len(joint_names), bool) if continuous is None else np.asarray(continuous, bool)
    names = list(joint_names)
    for j in np.flatnonzero(flags):
        values[:, j] = unwrap(values[:, j])
        names[j] = f"{names[j]} (unwrapped)"
    out = {}
    for group, idx in joint_groups(joint_names).items():
        entity = f"{root}/{group}" if group else root
        log_scalars(rec, entity, timeline, times, values[:, idx], names=[names[j] for j in idx],
                    colors=[PALETTE[i % len(PALETTE)] for i in range(len(idx))])
        out[group] = entity
    return out


def unwrap(angles: np.ndarray, reference: int | None = None) -> np.ndarray:
    """``angles (K,)`` (rad) unwrapped along time (``np.unwrap`` over the finite samples; NaN
    stay). With ``reference``, shifted by a multiple of 2 pi so that sample ``reference`` keeps
    its value (e.g. the via-point step, where the cost saw the wrapped angle)."""
    a = np.asarray(angles, dtype=float)
    out = a.copy()
    good = np.isfinite(a)
    if good.sum() > 1:
        out[good] = np.unwrap(a[good])
        if reference is not None and good[reference]:
            out[good] -= 2 * np.pi * np.round((out[reference] - a[reference]) / (2 * np.pi))
    return out


def log_scalars(
    rec: Recording | rr.RecordingStream,
    entity: str,
    timeline: str,
    times: np.ndarray | Iterable[float],
    values: np.ndarray | Iterable[float],
    names: Sequence[str] | None = None,
    colors: Sequence[Sequence[int]] | None = None,
    points: bool = False,
    widths: float | None = None,
) -> None:
    """Scalars at ``entity``: ``values (K,)`` or ``(K, d)`` (d series) against ``times (K,)``.

    ``timeline``: ``sim_time`` (s, duration) or ``iteration``/``episode`` (int sequence).
    ``names`` (d,) label the series in the plot legend, ``colors`` (d,) RGB; ``points`` draws
    markers instead of lines (via-point targets), ``widths`` the line width (ui points).
    """
    stream = _stream(rec)
    t = np.asarray(times)
    v = np.asarray(values, dtype=float)
    if len(t) != len(v):
        raise ValueError(f"{entity}: {len(t)} times but {len(v)} values")
    if v.ndim == 1:
        cols = rr.Scalars.columns(scalars=v)
    else:
        v = v.reshape(len(v), -1)
        cols = rr.Scalars.columns(scalars=v.ravel()).partition([v.shape[1]] * len(v))
    stream.send_columns(entity, indexes=[_time_column(timeline, t)], columns=cols)
    if names is None and colors is None and not points and widths is None:
        return
    kw: dict[str, Any] = {}
    if names is not None:
        kw["names"] = list(names)
    if colors is not None:
        kw["colors"] = [list(map(int, c)) for c in colors]
    if points:
        stream.log(entity, rr.SeriesPoints(marker_sizes=[5.0] * (1 if v.ndim == 1 else v.shape[1]), **kw),
                   static=True)
    else:
        if widths is not None:
            kw["widths"] = [float(widths)] * (1 if v.ndim == 1 else v.shape[1])
        stream.log(entity, rr.SeriesLines(**kw), static=True)


def _color_u8(color: Sequence[float] | np.ndarray) -> np.ndarray:
    """RGB(A) as uint8 (floats in [0, 1] scaled by 255)."""
    c = np.asarray(color, dtype=float)
    c = np.round(c * 255) if c.max(initial=0) <= 1.0 else c
    return c.astype(np.uint8)


def log_points_path(
    rec: Recording | rr.RecordingStream,
    entity: str,
    P: np.ndarray,
    color: Sequence[float] | np.ndarray = (30, 120, 220),
    radius: float = 0.006,
    line: bool = True,
    max_points: int = 500,
    static: bool = True,
) -> None:
    """3D points ``P (K, 3)`` (m, non-finite rows dropped), joined by a line strip when ``line``;
    a long path keeps at most about ``max_points`` of its points (:func:`decimate`). Static, or
    with ``static=False`` at the stream's current time (the caller's ``set_time``, e.g. an episode).

    ``color``: RGB(A), uint8 0-255 or floats in [0, 1].
    """
    stream = _stream(rec)
    P = np.asarray(P, dtype=float).reshape(-1, 3)
    P = P[np.all(np.isfinite(P), axis=1)]
    P = P[decimate(len(P), max_points)]
    c = _color_u8(color)
    stream.log(entity, rr.Points3D(P, colors=[c], radii=[radius]), static=static)
    if line and len(P) > 1:
        stream.log(entity, rr.LineStrips3D([P], colors=[c], radii=[radius / 2]), static=static)


def log_path_series(
    rec: Recording | rr.RecordingStream,
    entity: str,
    timeline: str,
    times: np.ndarray,
    paths: np.ndarray,
    color: Sequence[float] | np.ndarray = (30, 120, 220),
    radius: float = 0.004,
) -> None:
    """One path per time: ``paths (N, K, 3)`` (m) as a LineStrips3D at ``entity`` on ``timeline``
    at ``times (N,)`` (``send_columns``; non-finite points dropped), so each time shows its own
    path (a plan's iterations)."""
    paths = np.asarray(paths, dtype=float).reshape(len(times), -1, 3)
    strips = [p[np.all(np.isfinite(p), axis=1)] for p in paths]
    c = _color_u8(color)
    _stream(rec).send_columns(entity, indexes=[_time_column(timeline, np.asarray(times))],
                              columns=rr.LineStrips3D.columns(strips=strips, colors=[c] * len(strips),
                                                              radii=[radius] * len(strips)))
