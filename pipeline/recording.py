"""Rerun recordings of stage runs (SPEC §9).

One ``.rrd`` per stage run, written by :class:`Recording` (its own
``rr.RecordingStream``, never the global one, so parallel workers don't mix) with
``RecordingStream.save`` and a default blueprint: a 3D view of ``world/**`` and time
series of ``joints/**`` plus any extra roots (``task``, ``cost``, ...).

Entity layout::

    world/robot/<body>             Transform3D of the body in the world, on ``sim_time``
    world/robot/<body>/<geometry>  static primitive + static pose in the body frame
    joints/<joint>                 Scalars on ``sim_time`` (rad)

Timelines: ``sim_time`` (duration, s), ``iteration`` and ``episode`` (sequences).
Drake quaternions are wxyz, Rerun's xyzw; Rerun capsules start at z = 0 while
Drake's are centred on their frame, so they are shifted by -length/2 along z.
"""

from __future__ import annotations

import errno
import json
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Self

# Rerun's Rust side logs its own (coloured) error lines to stderr, e.g. when its file writer fails;
# the failure reaches the user as one line from the CLI instead. RUST_LOG is read when rerun loads.
os.environ.setdefault("RUST_LOG", "off")

import numpy as np  # noqa: E402
import rerun as rr  # noqa: E402
import rerun.blueprint as rrb  # noqa: E402
from pydrake.geometry import Box, Capsule, Cylinder, Ellipsoid, Role, Sphere  # noqa: E402
from pydrake.multibody.tree import BodyIndex  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

__all__ = [
    "SEQUENCE_TIMELINES",
    "Recording",
    "body_poses",
    "default_blueprint",
    "entity_name",
    "log_body_trajectory",
    "log_joint_series",
    "log_points_path",
    "log_robot_geometry",
    "log_scalars",
    "robot_eye",
    "rot_to_quat_xyzw",
]

ROBOT_PREFIX = "world/robot"
SEQUENCE_TIMELINES = frozenset({"iteration", "episode"})
DEFAULT_COLOR = (0.7, 0.7, 0.7, 1.0)
_UNSAFE = re.compile(r"[^A-Za-z0-9_\-.]")


def entity_name(name: str) -> str:
    """A Drake name as one entity-path part: scope (``model::``) dropped, odd characters -> ``_``."""
    return _UNSAFE.sub("_", name.rsplit("::", 1)[-1]) or "_"


Eye = tuple[Sequence[float], Sequence[float]]  # (camera position, look target), m


def default_blueprint(time_series: Sequence[str] = (), eye: Eye | None = None) -> rrb.Blueprint:
    """3D view of ``world/**`` beside time series of ``joints/**`` and of each extra root.

    ``time_series``: entity roots such as ``"task"`` or ``"cost/**"``; ``eye``: initial
    camera ``(position, look_target)`` in the world (m), see :func:`robot_eye`.
    """
    roots = ["joints", *[r.strip("/").removesuffix("/**") for r in time_series if r]]
    plots = [rrb.TimeSeriesView(origin=f"/{r}", name=r) for r in dict.fromkeys(roots)]
    controls = None
    if eye is not None:
        controls = rrb.EyeControls3D(position=list(map(float, eye[0])),
                                     look_target=list(map(float, eye[1])), eye_up=[0.0, 0.0, 1.0])
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="/world", contents="/world/**", name="robot",
                              eye_controls=controls),
            rrb.Vertical(*plots),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def _property_value(value: Any) -> Any:
    """A config value as something ``rr.AnyValues`` takes (nested values become JSON text)."""
    if isinstance(value, bool | int | float | str):
        return value
    return json.dumps(value, sort_keys=True, default=str)


class Recording:
    """A Rerun recording saved to ``path`` (context manager; ``.rec`` is the stream).

    ``name``: recording name shown in the viewer; ``time_series``: extra plot roots and
    ``eye``: initial camera, both for the default blueprint (:func:`default_blueprint`).

    ``properties`` (the run's config, key, ...) become recording properties under
    ``raico``, plus the whole dict as JSON text in ``raico_json``.
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
    ) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.rec = rr.RecordingStream(application_id, recording_id=recording_id)
        try:
            self.rec.save(self.path, default_blueprint=default_blueprint(time_series, eye))
        except RuntimeError as e:  # Rerun's "Failed to create file: ... (os error N)"
            raise _os_error(e, self.path) from None
        self.properties = dict(properties or {})
        if name is not None:
            self.rec.send_recording_name(name)
        if self.properties:
            values = {str(k): _property_value(v) for k, v in self.properties.items()}
            self.rec.send_property("raico", rr.AnyValues(**values))
            blob = json.dumps(self.properties, sort_keys=True, default=str)
            self.rec.send_property("raico_json", rr.AnyValues(json=blob))
        # Z up, as in Drake
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self._closed = False

    def close(self) -> None:
        """Flush everything to the file and close it (idempotent). ``OSError`` naming the file if
        Rerun's file writer failed (full disk, ...): then the stream is left as it is, since
        disconnecting a stream whose writer died blocks forever (rerun 0.41)."""
        if not self._closed:
            self._closed = True
            try:
                self.rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
            except RuntimeError as e:  # "File-writer thread shut down prematurely", or the timeout
                raise _os_error(e, self.path) from None
            self.rec.disconnect()
            _check_complete(self.path)

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


FLUSH_TIMEOUT_S = 600.0  # a flush ends as soon as the file is written (or its writer failed)
RRD_MAGIC, RRD_FOOTER = b"RRF2", b"RRF2FOOT"  # rerun 0.41's .rrd: header magic, footer magic + u32 version


def _check_complete(path: Path) -> None:
    """``OSError`` if Rerun's writer left ``path`` without its footer. When the last write fails
    (file size limit, full disk) inside ``disconnect``, Rerun only logs it: a truncated file
    would otherwise pass as a recording."""
    try:
        with open(path, "rb") as f:
            head = f.read(len(RRD_MAGIC))
            size = f.seek(0, os.SEEK_END)
            f.seek(max(0, size - len(RRD_FOOTER) - 4))
            tail = f.read()
    except OSError as e:
        raise OSError(e.errno, e.strerror, str(path)) from None
    if head == RRD_MAGIC and not (len(tail) == len(RRD_FOOTER) + 4 and tail.startswith(RRD_FOOTER)):
        code = _likely_errno(path)
        raise OSError(code or errno.EIO, os.strerror(code) if code else "Rerun's file writer did not finish the file",
                      str(path))


def _os_error(err: RuntimeError, path: Path) -> OSError:
    """Rerun's ``RuntimeError`` as an ``OSError`` for ``path``: its ``(os error N)`` if it names one,
    else what the folder says (full, read-only, too large a file)."""
    m = re.search(r"os error (\d+)", str(err))
    code = int(m.group(1)) if m else _likely_errno(path)
    if code is not None:
        return OSError(code, os.strerror(code), str(path))
    return OSError(errno.EIO, f"Rerun's file writer failed ({' '.join(str(err).split())})", str(path))


def _likely_errno(path: Path) -> int | None:
    """Why writes to ``path`` fail, as far as the file system says: full, read-only, file too large."""
    try:
        st = os.statvfs(path.parent)
        if st.f_bavail == 0 or (st.f_files > 0 and st.f_favail == 0):
            return errno.ENOSPC
        if st.f_flag & os.ST_RDONLY:
            return errno.EROFS
        import resource

        limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
        if limit != resource.RLIM_INFINITY and path.exists() and path.stat().st_size >= limit:
            return errno.EFBIG
    except (OSError, ImportError, ValueError):
        return None
    return None


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
    return None


def _bodies(plant: Any) -> list[Any]:
    return [plant.get_body(BodyIndex(i)) for i in range(plant.num_bodies())]


def log_robot_geometry(
    rec: Recording | rr.RecordingStream, robot: Any, prefix: str = ROBOT_PREFIX
) -> dict[str, list[str]]:
    """Log every illustration geometry as a static primitive under ``prefix/<body>/<geometry>``.

    Each geometry gets a static Transform3D: its pose in the body frame (m, xyzw).
    Returns ``{body entity name: [geometry entity names]}`` (bodies with geometry only).
    Unsupported shapes (meshes, half spaces) are skipped.
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
    robot's bodies at planning ``q (n_q,)`` (default posture if None)."""
    q = robot.default_q if q is None else q
    _, T, _ = body_poses(robot, np.atleast_2d(q))
    lo, hi = T[0].min(axis=0), T[0].max(axis=0)
    target = (lo + hi) / 2
    size = max(float(np.linalg.norm(hi - lo)), 0.3)
    direction = np.array([1.0, -0.75, 0.45])
    return target + 1.6 * size * direction / np.linalg.norm(direction), target


def _time_column(timeline: str, times: np.ndarray) -> rr.TimeColumn:
    """``sim_time`` and other float timelines as durations (s); ``iteration``/``episode``/ints as sequences."""
    t = np.asarray(times)
    if timeline in SEQUENCE_TIMELINES or np.issubdtype(t.dtype, np.integer):
        return rr.TimeColumn(timeline, sequence=t.astype(np.int64))
    return rr.TimeColumn(timeline, duration=t.astype(np.float64))


def log_body_trajectory(
    rec: Recording | rr.RecordingStream,
    robot: Any,
    times: np.ndarray,
    Q: np.ndarray,
    prefix: str = ROBOT_PREFIX,
    timeline: str = "sim_time",
    joints: bool = True,
) -> list[str]:
    """Log body world poses for ``times (K,)`` s and ``Q (K, n_q)`` rad with ``send_columns``.

    ``prefix/<body>`` gets Transform3D columns (translation m, quaternion xyzw); with
    ``joints`` also ``joints/<joint>`` Scalars. Returns the body entity names.
    """
    stream = _stream(rec)
    Q = np.atleast_2d(np.asarray(Q, dtype=float))
    times = np.asarray(times, dtype=float)
    if len(times) != len(Q):
        raise ValueError(f"times has {len(times)} samples but Q has {len(Q)}")
    names, T, R = body_poses(robot, Q)
    index = [_time_column(timeline, times)]
    entities = [entity_name(n) for n in names]
    for j, ent in enumerate(entities):
        stream.send_columns(f"{prefix}/{ent}", indexes=index,
                            columns=rr.Transform3D.columns(translation=T[:, j], quaternion=R[:, j]))
    if joints:
        log_joint_series(stream, robot.joint_names, times, Q, timeline=timeline)
    return entities


def log_joint_series(
    rec: Recording | rr.RecordingStream,
    joint_names: Sequence[str],
    times: np.ndarray,
    values: np.ndarray,
    root: str = "joints",
    timeline: str = "sim_time",
) -> None:
    """``root/<joint>`` Scalars: ``values (K, n)`` against ``times (K,)``."""
    values = np.atleast_2d(np.asarray(values, dtype=float))
    for j, name in enumerate(joint_names):
        log_scalars(rec, f"{root}/{entity_name(name)}", timeline, times, values[:, j])


def log_scalars(
    rec: Recording | rr.RecordingStream,
    entity: str,
    timeline: str,
    times: np.ndarray | Iterable[float],
    values: np.ndarray | Iterable[float],
    names: Sequence[str] | None = None,
) -> None:
    """Scalars at ``entity``: ``values (K,)`` or ``(K, d)`` (d series) against ``times (K,)``.

    ``timeline``: ``sim_time`` (s, duration) or ``iteration``/``episode`` (int sequence).
    ``names`` (d,) label the series in the plot legend.
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
    if names is not None:
        stream.log(entity, rr.SeriesLines(names=list(names)), static=True)


def log_points_path(
    rec: Recording | rr.RecordingStream,
    entity: str,
    P: np.ndarray,
    color: Sequence[float] | np.ndarray = (30, 120, 220),
    radius: float = 0.006,
    line: bool = True,
) -> None:
    """Static 3D points ``P (K, 3)`` (m), joined by a line strip when ``line``.

    ``color``: RGB(A), uint8 0-255 or floats in [0, 1].
    """
    stream = _stream(rec)
    P = np.asarray(P, dtype=float).reshape(-1, 3)
    c = np.asarray(color, dtype=float)
    c = np.round(c * 255) if c.max(initial=0) <= 1.0 else c
    c = c.astype(np.uint8)
    stream.log(entity, rr.Points3D(P, colors=[c], radii=[radius]), static=True)
    if line and len(P) > 1:
        stream.log(entity, rr.LineStrips3D([P], colors=[c], radii=[radius / 2]), static=True)
