"""Rollouts as MCAP files: ``trajectory.mcap`` beside a stage's ``recording.rrd``.

JSON-encoded messages with ``jsonschema`` schemas, one message per sample, ``log_time``
= ``publish_time`` = ``round(times * 1e9)`` ns:

- ``/joint_states`` (``raico.JointState``, like ``sensor_msgs/JointState``): planning joint
  ``name`` and ``position`` (rad), ``velocity`` (rad/s), ``effort`` (N m);
- ``/tf`` (``foxglove.FrameTransforms``, Foxglove's JSON layout): the world pose of every
  body, ``parent_frame_id`` ``"world"``, ``child_frame_id`` the body name, translation (m)
  and rotation (quaternion x, y, z, w);
- ``/task/<name>`` (``raico.TaskValue``): ``value`` (d,) of a task variable.

Non-finite numbers are written as JSON ``null`` (read back as NaN). A ``raico`` metadata
record names the robot and the joints. :func:`read_trajectory_mcap` reads it all back.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from mcap.writer import Writer

from raico.pipeline.recordings.rerun_io import body_poses

__all__ = ["JOINT_STATES", "TASK_PREFIX", "TF", "read_trajectory_mcap", "write_trajectory_mcap"]

JOINT_STATES = "/joint_states"
TF = "/tf"
TASK_PREFIX = "/task/"

_NUMBERS = {"type": "array", "items": {"type": ["number", "null"]}}
_TIME = {
    "type": "object",
    "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
    "required": ["sec", "nsec"],
}
_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
SCHEMAS: dict[str, dict[str, Any]] = {
    "raico.JointState": {
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "name": {"type": "array", "items": {"type": "string"}},
            "position": _NUMBERS,
            "velocity": _NUMBERS,
            "effort": _NUMBERS,
        },
        "required": ["timestamp", "name", "position"],
    },
    "foxglove.FrameTransforms": {
        "type": "object",
        "properties": {
            "transforms": {
                "type": "array",
                "items": {
                    "type": "object",
                    "properties": {
                        "timestamp": _TIME,
                        "parent_frame_id": {"type": "string"},
                        "child_frame_id": {"type": "string"},
                        "translation": _VEC3,
                        "rotation": _QUAT,
                    },
                },
            }
        },
    },
    "raico.TaskValue": {
        "type": "object",
        "properties": {"timestamp": _TIME, "name": {"type": "string"}, "value": _NUMBERS},
        "required": ["timestamp", "name", "value"],
    },
}


def _ns(times: np.ndarray) -> np.ndarray:
    """Seconds ``(K,)`` -> non-negative integer nanoseconds ``(K,)`` (MCAP times are unsigned)."""
    ns = np.round(np.asarray(times, dtype=float) * 1e9).astype(np.int64)
    if len(ns) and ns.min() < 0:
        raise ValueError("MCAP log times must be >= 0 s")
    return ns


def stamp_of(ns: int) -> dict[str, int]:
    return {"sec": int(ns // 1_000_000_000), "nsec": int(ns % 1_000_000_000)}


def _floats(x: Iterable[float]) -> list[float | None]:
    return [float(v) if math.isfinite(v) else None for v in np.asarray(x, dtype=float).ravel()]


def _unfloats(x: Iterable[float | None]) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in x], dtype=float)


def _rows(A: np.ndarray | None, K: int) -> np.ndarray | None:
    """``A`` as ``(K, d)`` floats (None stays None)."""
    return None if A is None else np.asarray(A, dtype=float).reshape(K, -1)


class _Channels:
    """Schemas registered once, one channel per topic."""

    def __init__(self, writer: Writer) -> None:
        self.writer = writer
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}

    def channel(self, topic: str, schema: str) -> int:
        if schema not in self.schemas:
            data = json.dumps(SCHEMAS[schema]).encode()
            self.schemas[schema] = self.writer.register_schema(schema, "jsonschema", data)
        if topic not in self.channels:
            self.channels[topic] = self.writer.register_channel(topic, "json", self.schemas[schema])
        return self.channels[topic]

    def write(self, topic: str, schema: str, seq: int, ns: int, msg: Mapping[str, Any]) -> None:
        self.write_json(topic, schema, seq, ns, json.dumps(msg, separators=(",", ":"), allow_nan=False))

    def write_json(self, topic: str, schema: str, seq: int, ns: int, text: str) -> None:
        """A message already encoded as compact JSON."""
        self.writer.add_message(self.channel(topic, schema), log_time=ns, data=text.encode(),
                                publish_time=ns, sequence=seq)


# Compact JSON of the per-sample messages written directly (the bytes json.dumps(msg, separators=(",", ":"))
# gives: a float as its repr, a non-finite one as null, keys in the messages' order): a recording holds
# thousands of them, and json.dumps of the nested dicts was a third of a plan recording's time; the floats of a
# whole array are formatted in one pass of the json module's C encoder (a Python repr per float was half the rest).
def _float_tokens(A) -> list[str]:
    """Every value of ``A`` (flattened) as JSON writes it: its repr, ``null`` for a non-finite one."""
    flat = np.asarray(A, dtype=float).ravel()
    if not flat.size:
        return []
    tokens = json.dumps(flat.tolist())[1:-1].split(", ")
    for i in np.flatnonzero(~np.isfinite(flat)):
        tokens[i] = "null"
    return tokens


def _json_rows(A: np.ndarray) -> list[str]:
    """``A (K, ...)`` as ``K`` JSON arrays of each row's values (flattened)."""
    K = len(A)
    d = int(np.prod(np.shape(A)[1:], dtype=int))
    tok = _float_tokens(A)
    return ["[" + ",".join(tok[k * d:(k + 1) * d]) + "]" for k in range(K)]


def _json_stamp(ns: int) -> str:
    return f'{{"sec":{ns // 1_000_000_000},"nsec":{ns % 1_000_000_000}}}'


def _json_joint_state(names_json: str, ns: int, q: str, v: str | None, u: str | None) -> str:
    """:func:`joint_state_message` as compact JSON (``q``, ``v``, ``u``: JSON arrays, :func:`_json_rows`)."""
    return ('{"timestamp":' + _json_stamp(ns) + ',"name":' + names_json + ',"position":' + q
            + ',"velocity":' + ("[]" if v is None else v) + ',"effort":' + ("[]" if u is None else u) + "}")


def _json_transforms(bodies_json: list[str], ns: int, T: list[str], R: list[str]) -> str:
    """:func:`transforms_message` as compact JSON (``bodies_json``: each body's name as a JSON string; ``T``, ``R``: the
    ``3 B`` translation and ``4 B`` xyzw rotation values as JSON tokens, :func:`_float_tokens`)."""
    stamp = _json_stamp(ns)
    parts = []
    for i, b in enumerate(bodies_json):
        tx, ty, tz = T[3 * i:3 * i + 3]
        rx, ry, rz, rw = R[4 * i:4 * i + 4]
        parts.append('{"timestamp":' + stamp + ',"parent_frame_id":"world","child_frame_id":' + b
                     + f',"translation":{{"x":{tx},"y":{ty},"z":{tz}}}'
                     + f',"rotation":{{"x":{rx},"y":{ry},"z":{rz},"w":{rw}}}}}')
    return '{"transforms":[' + ",".join(parts) + "]}"


def joint_state_message(names: list[str], ns: int, q: np.ndarray, v: np.ndarray | None,
                 u: np.ndarray | None) -> dict[str, Any]:
    msg: dict[str, Any] = {"timestamp": stamp_of(ns), "name": names, "position": _floats(q)}
    msg["velocity"] = [] if v is None else _floats(v)
    msg["effort"] = [] if u is None else _floats(u)
    return msg


def transforms_message(bodies: list[str], ns: int, T: np.ndarray, R: np.ndarray) -> dict[str, Any]:
    """``T (B, 3)`` m, ``R (B, 4)`` xyzw -> foxglove.FrameTransforms."""
    stamp = stamp_of(ns)
    return {"transforms": [
        {"timestamp": stamp, "parent_frame_id": "world", "child_frame_id": b,
         "translation": dict(zip("xyz", map(float, t), strict=True)),
         "rotation": dict(zip("xyzw", map(float, r), strict=True))}
        for b, t, r in zip(bodies, T, R, strict=True)
    ]}


def write_trajectory_mcap(
    path: str | Path,
    robot: Any,
    times: np.ndarray,
    Q: np.ndarray,
    V: np.ndarray | None = None,
    U: np.ndarray | None = None,
    task_values: Mapping[str, np.ndarray] | None = None,
) -> Path:
    """Write a rollout as MCAP: ``times (K,)`` s (>= 0), ``Q``/``V``/``U (K, n_q)`` in planning
    coordinates (rad, rad/s, N m), ``task_values`` ``{name: (K,) or (K, d)}``. Returns ``path``.
    """
    path = Path(path)
    Q = np.atleast_2d(np.asarray(Q, dtype=float))
    K = len(Q)
    ns = _ns(times)
    if len(ns) != K:
        raise ValueError(f"times has {len(ns)} samples but Q has {K}")
    V, U = _rows(V, K), _rows(U, K)
    tasks = {k: _rows(v, K) for k, v in (task_values or {}).items()}
    bodies, T, R = body_poses(robot, Q)
    names = list(robot.joint_names)
    try:
        _write_mcap(path, robot, names, bodies, T, R, ns, Q, V, U, tasks)
    except OSError as e:  # a full disk, a read-only folder: the path and the cause (the writer's errors name none)
        raise OSError(e.errno, e.strerror or str(e), str(e.filename or path)) from None
    return path


def _write_mcap(path: Path, robot: Any, names: list[str], bodies: list[str], T, R, ns, Q, V, U,
                tasks: Mapping[str, np.ndarray | None]) -> None:
    K = len(Q)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="raico")
        writer.add_metadata("raico", {"robot": robot.name, "joint_names": json.dumps(names),
                                      "bodies": json.dumps(bodies)})
        ch = _Channels(writer)
        names_json = json.dumps(names, separators=(",", ":"))
        bodies_json = [json.dumps(b) for b in bodies]
        task_json = {name: json.dumps(name) for name in tasks}
        q_json = _json_rows(Q)
        v_json = None if V is None else _json_rows(V)
        u_json = None if U is None else _json_rows(U)
        task_rows = {name: _json_rows(val) for name, val in tasks.items()}
        nt, nr = 3 * len(bodies), 4 * len(bodies)
        t_tok, r_tok = _float_tokens(T), _float_tokens(R)
        for k in range(K):
            t = int(ns[k])
            ch.write_json(JOINT_STATES, "raico.JointState", k, t, _json_joint_state(
                names_json, t, q_json[k], None if v_json is None else v_json[k], None if u_json is None else u_json[k]))
            ch.write_json(TF, "foxglove.FrameTransforms", k, t, _json_transforms(
                bodies_json, t, t_tok[k * nt:(k + 1) * nt], r_tok[k * nr:(k + 1) * nr]))
            for name, rows in task_rows.items():
                ch.write_json(TASK_PREFIX + name, "raico.TaskValue", k, t, '{"timestamp":' + _json_stamp(t)
                              + ',"name":' + task_json[name] + ',"value":' + rows[k] + "}")
        writer.finish()


def read_trajectory_mcap(path: str | Path) -> dict[str, Any]:
    """Read a file from :func:`write_trajectory_mcap`.

    Returns ``times (K,)`` s, ``joint_names``, ``position``/``velocity``/``effort``
    ``(K, n)`` (velocity/effort None if not written), ``bodies`` (B names),
    ``translation (K, B, 3)``, ``rotation (K, B, 4)`` xyzw, ``task`` ``{name: (K, d)}``,
    ``metadata`` (dict of dicts) and ``topics``.
    """
    joints: list[dict[str, Any]] = []
    tfs: list[dict[str, Any]] = []
    tasks: dict[str, list[list[float | None]]] = {}
    times: list[int] = []
    with Path(path).open("rb") as f:
        reader = make_reader(f)
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        topics = sorted(c.topic for c in reader.get_summary().channels.values())
        for _, channel, message in reader.iter_messages(log_time_order=True):
            msg = json.loads(message.data)
            if channel.topic == JOINT_STATES:
                joints.append(msg)
                times.append(message.log_time)
            elif channel.topic == TF:
                tfs.append(msg)
            elif channel.topic.startswith(TASK_PREFIX):
                tasks.setdefault(channel.topic[len(TASK_PREFIX):], []).append(msg["value"])
    return {
        "times": np.asarray(times, dtype=float) / 1e9,
        "joint_names": joints[0]["name"] if joints else [],
        "position": _stack(joints, "position"),
        "velocity": _stack(joints, "velocity"),
        "effort": _stack(joints, "effort"),
        "bodies": [t["child_frame_id"] for t in tfs[0]["transforms"]] if tfs else [],
        "translation": np.array([[[t["translation"][a] for a in "xyz"] for t in m["transforms"]]
                                 for m in tfs], dtype=float),
        "rotation": np.array([[[t["rotation"][a] for a in "xyzw"] for t in m["transforms"]]
                              for m in tfs], dtype=float),
        "task": {k: np.array([_unfloats(v) for v in vals]) for k, vals in tasks.items()},
        "metadata": metadata,
        "topics": topics,
    }


def _stack(msgs: list[dict[str, Any]], key: str) -> np.ndarray | None:
    rows = [m.get(key) or [] for m in msgs]
    if not rows or not any(rows):
        return None
    return np.array([_unfloats(r) for r in rows])
