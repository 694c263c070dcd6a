"""Tests of the Rerun recordings (raico/pipeline/recordings/rerun_io.py) and MCAP rollouts (raico/pipeline/recordings/mcap_io.py)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from mcap.reader import make_reader
from pydrake.multibody.tree import BodyIndex
from rerun.chunk import RrdReader

from raico.pipeline.recordings.mcap_io import read_trajectory_mcap, write_trajectory_mcap
from raico.pipeline.recordings.rerun_io import (
    MAX_POSES,
    Recording,
    body_poses,
    continuous_joints,
    decimate,
    joint_groups,
    log_body_trajectory,
    log_points_path,
    log_robot_geometry,
    log_scalars,
    plot_indices,
    pose_indices,
    robot_eye,
    rot_to_quat_xyzw,
    unwrap,
)
from raico.plants.robots import PLANTS, shared_robot
from tests.tolerance import assert_close

K = 20
_VENV_RERUN = Path(sys.executable).parent / "rerun"
RERUN = str(_VENV_RERUN) if _VENV_RERUN.exists() else shutil.which("rerun")
needs_cli = pytest.mark.skipif(RERUN is None, reason="rerun CLI not installed")


def _trajectory(robot) -> tuple[np.ndarray, np.ndarray]:
    """``K`` samples over 1 s around the default posture: times (K,), Q (K, n_q)."""
    t = np.linspace(0.0, 1.0, K)
    wiggle = 0.2 * np.sin(2 * np.pi * t)[:, None] * np.linspace(0.5, 1.0, robot.n_q)
    return t, robot.default_q + wiggle


def _chunks(path: Path) -> list:
    return RrdReader(path).stream().to_chunks()


def _rows(chunks: list, entity: str, timeline: str | None) -> int:
    """Rows at ``entity`` on ``timeline`` (None: static rows)."""
    return sum(c.num_rows for c in chunks if c.entity_path == entity
               and (c.is_static if timeline is None else timeline in c.timeline_names))


def _column(chunks: list, entity: str, component: str) -> list:
    for c in chunks:
        batch = c.to_record_batch()
        if c.entity_path == entity and component in batch.schema.names:
            return batch.column(component).to_pylist()
    raise AssertionError(f"no {component} at {entity}")


def _write(path: Path, robot) -> tuple[dict[str, list[str]], list[str]]:
    t, Q = _trajectory(robot)
    props = {"stage": "plan", "key": "0123abcd", "config": {"T": K, "alpha": [0.5, 1.0]}}
    with Recording(path, properties=props, name=f"test {robot.name}",
                   time_series=["task", "cost/**"], eye=robot_eye(robot)) as rec:
        geometry = log_robot_geometry(rec, robot)
        bodies = log_body_trajectory(rec, robot, t, Q)
        log_scalars(rec, "cost/total", "iteration", np.arange(5), np.linspace(3, 1, 5))
        log_scalars(rec, "task/ee", "sim_time", t, np.zeros((K, 3)), names=["x", "y", "z"])
        log_points_path(rec, "world/via_points", np.zeros((3, 3)), (1.0, 0.0, 0.0))
    return geometry, bodies


@pytest.mark.numerics
@pytest.mark.parametrize("name", PLANTS)
def test_recording_has_every_body_and_joint(tmp_path: Path, name: str) -> None:
    robot = shared_robot(name)
    path = tmp_path / f"{name}.rrd"
    geometry, bodies = _write(path, robot)
    # every illustration geometry of the scene graph (none of these plants uses meshes)
    from pydrake.geometry import Role

    inspector = robot.scene_graph.model_inspector()
    frames = [robot.plant.GetBodyFrameIdIfExists(BodyIndex(i)) for i in range(robot.plant.num_bodies())]
    n_geometries = sum(len(inspector.GetGeometries(f, Role.kIllustration)) for f in frames if f is not None)
    assert sum(len(g) for g in geometry.values()) == n_geometries == {"pendulum": 3, "cartpole": 4, "arm5": 11, "biorob": 11,
                                                                       "nao": 30}[name]
    reader = RrdReader(path)
    assert [s.application_id for s in reader.recordings()] == ["raico"]
    assert len(reader.blueprints()) == 1
    chunks = _chunks(path)
    for body, geoms in geometry.items():
        assert body in bodies
        assert _rows(chunks, f"/world/robot/{body}", "sim_time") == K, body
        for g in geoms:
            assert _rows(chunks, f"/world/robot/{body}/{g}", None) == 1, (body, g)
    assert len(bodies) == robot.plant.num_bodies() - 1
    # one entity per limb (the Nao) or for all joints, its series named after the joints
    continuous = continuous_joints(robot)
    named = [j + (" (unwrapped)" if c else "") for j, c in zip(robot.joint_names, continuous, strict=True)]
    groups = joint_groups(robot.joint_names)
    assert sorted(i for idx in groups.values() for i in idx) == list(range(robot.n_q))
    for group, idx in groups.items():
        entity = f"/joints/{group}" if group else "/joints"
        assert _rows(chunks, entity, "sim_time") == K
        assert _column(chunks, entity, "SeriesLines:names")[0] == [named[i] for i in idx]
    assert _rows(chunks, "/cost/total", "iteration") == 5
    assert _rows(chunks, "/task/ee", "sim_time") == K
    # the logged poses are Drake's (xyzw)
    names, T, R = body_poses(robot, _trajectory(robot)[1])
    j = len(names) - 1
    trans = np.array(_column(chunks, f"/world/robot/{bodies[j]}", "Transform3D:translation"))
    quat = np.array(_column(chunks, f"/world/robot/{bodies[j]}", "Transform3D:quaternion"))
    np.testing.assert_allclose(trans.reshape(K, 3), T[:, j], atol=1e-6)
    np.testing.assert_allclose(quat.reshape(K, 4), R[:, j], atol=1e-6)


def test_joint_groups_by_limb() -> None:
    groups = joint_groups(shared_robot("nao").joint_names)
    assert list(groups) == ["head", "left_arm", "right_arm", "left_leg", "right_leg"]
    names = shared_robot("nao").joint_names
    assert [names[i] for i in groups["left_arm"]] == ["LShoulderPitch", "LShoulderRoll", "LElbowYaw", "LElbowRoll",
                                                      "LWristYaw", "LHand"]
    assert [names[i] for i in groups["right_leg"]] == ["RHipRoll", "RHipPitch", "RKneePitch", "RAnklePitch",
                                                       "RAnkleRoll"]
    assert [len(v) for v in groups.values()] == [2, 6, 6, 6, 5]
    assert joint_groups(shared_robot("arm5").joint_names) == {"": [0, 1, 2, 3, 4]}
    assert joint_groups(["HeadYaw", "theta"]) == {"": [0, 1]}  # a name without a limb: no groups


def test_decimation_rule() -> None:
    idx = decimate(1001, MAX_POSES, keep=[333, 500])
    assert idx[0] == 0 and idx[-1] == 1000 and {333, 500} <= set(idx) and len(idx) <= MAX_POSES + 3
    assert np.all(np.diff(idx) > 0) and np.diff(idx).max() <= 6
    np.testing.assert_array_equal(decimate(150, MAX_POSES), np.arange(150))
    # the pendulum's swing-up (751 samples, 3 bodies) at full rate; the arm's 1001 x 7 and the Nao's 301 x 31 not
    assert len(pose_indices(751, 3)) == 751
    assert len(pose_indices(1001, 7)) <= MAX_POSES + 1 and len(pose_indices(301, 31)) <= MAX_POSES + 1
    assert len(plot_indices(1001)) == 1001 and len(plot_indices(10_001)) <= 2001


@pytest.mark.numerics
def test_unwrap_angles() -> None:
    true = np.linspace(2.0, 4.5, 50)  # through +pi: the wrapped trace jumps by -2 pi
    wrapped = np.angle(np.exp(1j * true))
    assert np.abs(np.diff(wrapped)).max() > 6
    assert_close(unwrap(wrapped), true, scale=2 * np.pi)   # turns added: rounding at that scale
    # shifted so that the reference sample keeps its (wrapped) value
    out = unwrap(wrapped, reference=49)
    assert out[49] == pytest.approx(wrapped[49]) and np.abs(np.diff(out)).max() < 0.1
    gap = wrapped.copy()
    gap[10] = np.nan
    assert np.isnan(unwrap(gap)[10]) and np.abs(np.diff(np.delete(unwrap(gap), 10))).max() < 0.2
    assert continuous_joints(shared_robot("pendulum")).tolist() == [True]
    assert not continuous_joints(shared_robot("arm5")).any() and not continuous_joints(shared_robot("nao")).any()


@pytest.mark.numerics
def test_recording_properties_and_capsule_offset(tmp_path: Path) -> None:
    path = tmp_path / "arm5.rrd"
    _write(path, shared_robot("arm5"))
    chunks = _chunks(path)
    props = _column(chunks, "/__properties/raico_json", "json")
    assert json.loads(props[0][0])["key"] == "0123abcd"
    assert _column(chunks, "/__properties/raico", "key") == [["0123abcd"]]
    assert _column(chunks, "/__properties", "RecordingInfo:name") == [["test arm5"]]
    # arm5 upper arm: capsule of length 0.5, centred in Drake, starting at z=0 in Rerun
    length = _column(chunks, "/world/robot/upper_arm/upper_arm", "Capsules3D:lengths")[0][0]
    shift = _column(chunks, "/world/robot/upper_arm/upper_arm", "Capsules3D:translations")[0][0]
    assert length == pytest.approx(0.5)
    np.testing.assert_allclose(shift, [0.0, 0.0, -0.25])


def test_unset_property_then_a_number_converts(tmp_path: Path) -> None:
    """An option unset (None) in one run and a number in the next, in one process: no conversion
    warning (Rerun types a property name by its first value), and None stays in the JSON."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Recording(tmp_path / "a.rrd", properties={"window": None, "key": "a"}).close()
        Recording(tmp_path / "b.rrd", properties={"window": 50, "key": "b"}).close()
    chunks = _chunks(tmp_path / "a.rrd")
    assert json.loads(_column(chunks, "/__properties/raico_json", "json")[0][0])["window"] is None
    assert _column(_chunks(tmp_path / "b.rrd"), "/__properties/raico", "window") == [[50]]


def test_parallel_recordings_do_not_mix(tmp_path: Path) -> None:
    a, b = Recording(tmp_path / "a.rrd"), Recording(tmp_path / "b.rrd")
    log_scalars(a, "cost/a", "iteration", np.arange(3), np.ones(3))
    log_scalars(b, "cost/b", "iteration", np.arange(4), np.ones(4))
    a.close()
    b.close()
    assert rr.get_global_data_recording() is None
    ents_a = {c.entity_path for c in _chunks(tmp_path / "a.rrd")}
    ents_b = {c.entity_path for c in _chunks(tmp_path / "b.rrd")}
    assert "/cost/a" in ents_a and "/cost/b" not in ents_a
    assert "/cost/b" in ents_b and "/cost/a" not in ents_b


@pytest.mark.numerics
def test_quaternions_match_drake() -> None:
    from pydrake.math import RollPitchYaw, RotationMatrix

    rng = np.random.default_rng(0)
    rots = [RotationMatrix(RollPitchYaw(rng.uniform(-3, 3, 3))) for _ in range(50)]
    q = rot_to_quat_xyzw(np.array([r.matrix() for r in rots]))
    wxyz = np.array([r.ToQuaternion().wxyz() for r in rots])
    drake_xyzw = np.concatenate([wxyz[:, 1:], wxyz[:, :1]], axis=1)
    # same rotation: q and -q are equal
    np.testing.assert_allclose(np.abs(np.sum(q * drake_xyzw, axis=1)), 1.0, atol=1e-9)


@needs_cli
def test_rrd_verify(tmp_path: Path) -> None:
    path = tmp_path / "nao.rrd"
    _write(path, shared_robot("nao"))
    out = subprocess.run([RERUN, "rrd", "verify", str(path)], capture_output=True, text=True, check=False,
                         timeout=60)
    assert out.returncode == 0, out.stderr


def _rollout(robot) -> dict:
    t, Q = _trajectory(robot)
    V = np.gradient(Q, t, axis=0)
    U = np.zeros_like(Q)
    U[0, 0] = np.nan
    tasks = {"ee": np.arange(3 * K, dtype=float).reshape(K, 3), "cost": np.ones(K)}
    return {"times": t, "Q": Q, "V": V, "U": U, "task_values": tasks}


def test_mcap_round_trip(tmp_path: Path) -> None:
    robot = shared_robot("nao")
    r = _rollout(robot)
    path = write_trajectory_mcap(tmp_path / "trajectory.mcap", robot, **r)
    with path.open("rb") as f:  # plain mcap reader: schemas and channels
        summary = make_reader(f).get_summary()
    schemas = {s.name: s.encoding for s in summary.schemas.values()}
    assert set(schemas.values()) == {"jsonschema"}
    assert {c.message_encoding for c in summary.channels.values()} == {"json"}
    assert summary.statistics.message_count == 4 * K
    d = read_trajectory_mcap(path)
    assert d["topics"] == ["/joint_states", "/task/cost", "/task/ee", "/tf"]
    assert d["metadata"]["raico"]["robot"] == "nao"
    assert d["joint_names"] == list(robot.joint_names)
    np.testing.assert_allclose(d["times"], r["times"], atol=1e-9)
    np.testing.assert_allclose(d["position"], r["Q"])
    np.testing.assert_allclose(d["velocity"], r["V"])
    np.testing.assert_array_equal(np.isnan(d["effort"]), np.isnan(r["U"]))
    np.testing.assert_allclose(d["task"]["ee"], r["task_values"]["ee"])
    np.testing.assert_array_equal(d["task"]["cost"], np.ones((K, 1)))
    names, T, R = body_poses(robot, r["Q"])
    assert d["bodies"] == names
    np.testing.assert_allclose(d["translation"], T)
    np.testing.assert_allclose(d["rotation"], R)


def test_mcap_messages_are_the_bytes_json_dumps_gives(tmp_path: Path) -> None:
    """The messages formatted directly (floats in one pass of the json encoder) are byte for byte what
    ``json.dumps(msg, separators=(",", ":"))`` writes for the same message as a dict (non-finite values as null)."""
    from raico.pipeline.recordings.mcap_io import joint_state_message, stamp_of, transforms_message

    robot = shared_robot("nao")
    r = _rollout(robot)
    r["V"][1, 2], r["V"][2, 0], r["task_values"]["ee"][3, 1] = np.inf, -np.inf, np.nan
    r["Q"][4, 5] = -0.0
    path = write_trajectory_mcap(tmp_path / "t.mcap", robot, **r)
    names, T, R = body_poses(robot, r["Q"])
    dumps = lambda m: json.dumps(m, separators=(",", ":"), allow_nan=False)  # noqa: E731
    with path.open("rb") as f:
        got = {}
        for _, channel, message in make_reader(f).iter_messages():
            got.setdefault(channel.topic, []).append(message.data.decode())
    for k, ns in enumerate(message_times := [int(round(t * 1e9)) for t in r["times"]]):
        assert got["/joint_states"][k] == dumps(joint_state_message(list(robot.joint_names), ns, r["Q"][k], r["V"][k],
                                                             r["U"][k]))
        assert got["/tf"][k] == dumps(transforms_message(names, ns, T[k], R[k]))
        value = [float(v) if np.isfinite(v) else None for v in r["task_values"]["ee"][k]]
        assert got["/task/ee"][k] == dumps({"timestamp": stamp_of(ns), "name": "ee", "value": value})
    assert len(message_times) == K and "null" in got["/joint_states"][1] and "-0.0" in got["/joint_states"][4]


def test_mcap_without_optional_channels(tmp_path: Path) -> None:
    robot = shared_robot("pendulum")
    t, Q = _trajectory(robot)
    d = read_trajectory_mcap(write_trajectory_mcap(tmp_path / "p.mcap", robot, t, Q))
    assert d["velocity"] is None and d["effort"] is None and d["task"] == {}
    names, T, R = body_poses(robot, Q)
    assert d["bodies"] == names and d["translation"].shape == (K, robot.plant.num_bodies() - 1, 3)
    np.testing.assert_allclose(d["translation"], T)
    np.testing.assert_allclose(d["rotation"], R)
    np.testing.assert_allclose(d["position"], Q)


@needs_cli
def test_rerun_converts_mcap(tmp_path: Path) -> None:
    robot = shared_robot("arm5")
    src = write_trajectory_mcap(tmp_path / "trajectory.mcap", robot, **_rollout(robot))
    dst = tmp_path / "trajectory.rrd"
    out = subprocess.run([RERUN, "mcap", "convert", str(src), "-o", str(dst),
                          "--application-id", "raico"],
                         capture_output=True, text=True, check=False, timeout=60)
    assert out.returncode == 0, out.stderr
    entities = {c.entity_path for c in _chunks(dst)}
    assert {"/joint_states", "/tf", "/task/ee"} <= entities


def _blueprint(path: Path) -> tuple[dict[str, str], str | None]:
    """View name -> view class of the file's blueprint, and the timeline its time panel selects."""
    reader = RrdReader(path)
    views, timeline = {}, None
    for c in reader.stream(store=reader.blueprints()[0]).to_chunks():
        batch = c.to_record_batch()
        cols = batch.schema.names
        if "ViewBlueprint:display_name" in cols:
            views[batch.column("ViewBlueprint:display_name").to_pylist()[0][0]] = \
                batch.column("ViewBlueprint:class_identifier").to_pylist()[0][0]
        if "TimePanelBlueprint:timeline" in cols:
            timeline = batch.column("TimePanelBlueprint:timeline").to_pylist()[0][0]
    return views, timeline


def _plan(tmp_path: Path, *args) -> Path:
    from typer.testing import CliRunner

    from raico.pipeline.interface.cli import app

    res = CliRunner().invoke(app, ["plan", *map(str, args), "--solver", "raico", "--alpha", "1", "--iterations", "2",
                                   "--json", "--quiet", "--artifacts", str(tmp_path)])
    assert res.exit_code == 0, res.output
    return Path(json.loads(res.stdout.strip().splitlines()[-1])["recording"])


def _names(chunks: list) -> dict[str, list[str]]:
    """Entity -> the names of its series (lines or points)."""
    out = {}
    for c in chunks:
        batch = c.to_record_batch()
        for col in ("SeriesLines:names", "SeriesPoints:names"):
            if c.is_static and col in batch.schema.names:
                out[c.entity_path] = batch.column(col).to_pylist()[0]
    return out


def test_nao_plan_recording_layout(tmp_path: Path) -> None:
    """Grouped legends, a decimated motion, the cost on every timeline and a pose on ``iteration``."""
    rrd = _plan(tmp_path, "--plant", "nao", "--task", "balance", "--dynamics", "pseudo")
    chunks = _chunks(rrd)
    names = _names(chunks)
    # no x[i] legends: vectors are named entities, the joints and controls grouped by limb
    assert not [n for ns in names.values() for n in ns if "[" in n]
    assert names["/task/cog/value"] == ["x", "y", "z"] and names["/task/cog/target"] == ["x*", "y*", "z*"]
    assert _rows(chunks, "/task/cog/target", "sim_time") == 3  # the three CoG via-points share the cog map
    assert names["/task/r_sole/value"] == ["x", "y", "z"] and _rows(chunks, "/task/r_sole/deviation", "sim_time") == 301
    assert len(names["/joints/left_leg"]) == 6 and len(names["/control/right_arm"]) == 6
    assert sum(len(names[f"/joints/{g}"]) for g in ("head", "left_arm", "right_arm", "left_leg", "right_leg")) == 25
    # 301 samples x 31 bodies: decimated poses (the last and the via-point steps kept), plots at full rate
    rows = _rows(chunks, "/world/robot/torso", "sim_time")
    assert 100 <= rows <= MAX_POSES + 4
    assert _rows(chunks, "/joints/left_leg", "sim_time") == 301
    # the cost per iteration: a time series on iteration and a static bar chart (iteration 0: the initial cost)
    assert _rows(chunks, "/cost/total", "iteration") == 2
    bars = _column(chunks, "/cost/log10_per_iteration", "BarChart:abscissa")
    assert bars[0][0]["buffer"] == [0.0, 1.0, 2.0]
    # every body has a pose per iteration on the iteration timeline (no collapse to the world origin), and
    # each iteration (0: the initial trajectory) draws its CoG and hand paths
    robot = shared_robot("nao")
    on_iteration = {c.entity_path for c in chunks if "iteration" in c.timeline_names}
    bodies = {e for e in on_iteration if e.startswith("/world/robot/")}
    assert len(bodies) == robot.plant.num_bodies() - 1 and _rows(chunks, "/world/robot/torso", "iteration") == 3
    assert {e for e in on_iteration if e.startswith("/world/iterations/")} == {
        "/world/iterations/cog", "/world/iterations/l_gripper", "/world/iterations/r_gripper"}
    assert all(_rows(chunks, f"/world/iterations/{p}", "iteration") == 3 for p in ("cog", "l_gripper", "r_gripper"))
    views, timeline = _blueprint(rrd)
    assert timeline == "sim_time"
    # an application id per layout: a viewer keeps one active blueprint per application id
    assert [s.application_id for s in RrdReader(rrd).recordings()] == ["raico-plan-nao-balance"]
    assert views["robot"] == "3D" and views["log10 cost per iteration"] == "BarChart"
    assert views["cog (m)"] == "TimeSeries" and views["r_sole: deviation (m)"] == "TimeSeries"
    assert {"joints: head", "joints: left_leg", "control: right_leg"} <= set(views)


def test_arm_plan_recording_unwraps_the_roll(tmp_path: Path) -> None:
    rrd = _plan(tmp_path, "--plant", "arm5", "--task", "reach-roll", "--dynamics", "analytic")
    chunks = _chunks(rrd)
    names = _names(chunks)
    assert names["/task/roll/value"] == ["roll (unwrapped)"] and names["/task/ee/value"] == ["x", "y", "z"]
    assert _rows(chunks, "/task/ee/target", "sim_time") == 2 and _rows(chunks, "/task/roll/target", "sim_time") == 2
    roll = np.concatenate([np.asarray(v).ravel() for v in _column(chunks, "/task/roll/value", "Scalars:scalars")])
    assert len(roll) == 1001 and np.abs(np.diff(roll)).max() < 1.0
    assert 150 <= _rows(chunks, "/world/robot/hand", "sim_time") <= MAX_POSES + 3  # 1001 samples: decimated
    assert {c.entity_path for c in chunks if c.is_static} >= {"/world/paths/ee", "/world/targets/ee"}
    assert _rows(chunks, "/world/iterations/ee", "iteration") == 3  # the initial trajectory and 2 iterations
