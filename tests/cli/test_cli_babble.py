"""End-to-end CLI tests of babble, ls and show, through Typer's CliRunner and a real process."""

import json
import os
import signal
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

from raico.pipeline.engine.cache import Cache
from raico.pipeline.interface.cli import app
from tests.tolerance import assert_close, close


def test_help_lists_the_stages(raico):
    res = raico("--help")
    assert res.exit_code == 0
    commands = res.output.split("Commands:")[1].split("\n\n")[0]   # the section, not the docs line after it
    listed = [ln.split()[0] for ln in commands.splitlines() if ln.startswith("  ")]
    assert {"babble", "plan", "execute", "evaluate", "reproduce", "ls", "show"} <= set(listed)
    from raico.stages.registry import stage_names

    assert sorted(listed) == sorted([*stage_names(), *(c.name or c.callback.__name__ for c in app.registered_commands),
                                     *(g.name for g in app.registered_groups)])


@pytest.mark.numerics
def test_babble_pendulum_writes_artifact_and_hits_cache(raico, tmp_path):
    res = raico("babble", "--plant", "pendulum", "--episodes", 3, "--json", "--artifacts", tmp_path)
    assert res.exit_code == 0, res.output
    line = json.loads(res.stdout.strip().splitlines()[-1])
    assert set(line) == {"stage", "key", "path", "cached", "status", "metrics", "recording"}
    assert line["cached"] is False and line["stage"] == "babble"
    folder = Path(line["path"])
    assert folder == tmp_path / "babble" / line["key"]
    for name in ("meta.json", "data.npz", "recording.rrd", "trajectory.mcap"):
        assert (folder / name).is_file(), name
    meta = json.loads((folder / "meta.json").read_text())
    assert meta["config"]["episodes"] == 3 and meta["config"]["plant"] == "pendulum"
    assert meta["packages"]["drake"] == metadata.version("drake")
    assert meta["status"] == line["status"] == "ok" and meta["metrics"] == line["metrics"]
    data = np.load(folder / "data.npz")
    assert data["q"].shape == (3, 501, 1) and data["u"].shape == data["qddot"].shape
    assert np.abs(data["u"]).max() <= 10.0 + 1e-9
    # the metrics are the stored arrays': 3 episodes of 1 s at 2 ms (both ends), tracking error
    m = line["metrics"]
    assert (m["episodes"], m["samples"]) == (3, 3 * 501)
    assert m["max_abs_u"] == np.abs(data["u"]).max()
    assert m["rms_tracking_error"] == pytest.approx(np.sqrt(np.mean((data["q"] - data["q_des"]) ** 2)), rel=1e-9)
    assert_close(data["t"], np.arange(501) * 0.002, scale=1.0)   # seconds
    # same command again: served from the cache, the stage is not run (data file untouched)
    mtime = (folder / "data.npz").stat().st_mtime_ns
    res2 = raico("babble", "--plant", "pendulum", "--episodes", 3, "--json", "--artifacts", tmp_path)
    line2 = json.loads(res2.stdout.strip().splitlines()[-1])
    assert line2["cached"] is True and line2["key"] == line["key"]
    assert (folder / "data.npz").stat().st_mtime_ns == mtime
    rec = folder / "recording.rrd"
    assert f"babble {line['key']}: cached -> {folder} [ok]; recording {rec}" in res2.stderr.splitlines()
    assert line2["metrics"] == line["metrics"] and line2["recording"] == line["recording"] == str(rec)
    ls = raico("ls", "--artifacts", tmp_path)
    size = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())
    samples = f"samples={line['metrics']['samples']:.4g}"
    assert ls.exit_code == 0 and ls.output.splitlines() == [
        f"babble    {line['key']}  {'pendulum':40s} {'ok':15s} {samples:24s} {meta['created']:20s} "
        f"{size / 1e6:8.2f} MB  {folder}"]
    assert raico("ls", "--plant", "arm5", "--artifacts", tmp_path).output == ""
    assert raico("ls", "babble", "--plant", "pendulum", "--artifacts", tmp_path).output == ls.output
    show = raico("show", line["key"], "--artifacts", tmp_path)
    assert show.exit_code == 0
    shown = json.loads(show.output)
    assert shown["path"] == str(folder) and shown["recording"] == str(rec)
    assert {k: shown[k] for k in ("stage", "key", "config", "status", "metrics", "timings")} == \
        {k: meta[k] for k in ("stage", "key", "config", "status", "metrics", "timings")}


@pytest.mark.numerics
def test_babble_data_are_consistent_with_the_plant(raico, tmp_path):
    """qddot recorded equals the pendulum's equation of motion at the recorded (q, qdot, u)."""
    res = raico("babble", "--plant", "pendulum", "--episodes", 1, "--no-record", "--json",
                 "--artifacts", tmp_path)
    d = np.load(Path(json.loads(res.stdout.splitlines()[-1])["path"]) / "data.npz")
    q, v, a, u = d["q"][0, :, 0], d["qdot"][0, :, 0], d["qddot"][0, :, 0], d["u"][0, :, 0]
    assert np.allclose(a, u - v - 9.81 * np.sin(q), rtol=1e-4, atol=1e-4)


@pytest.mark.numerics
def test_babble_torques_follow_the_saturated_pd_law():
    """The Drake-native controller (TrajectorySource -> PidController -> Saturation) applies
    ``clip(kp (q_des - q) + kd (qdot_des - qdot), -u_max, u_max)`` at every sample, on a multi-joint arm."""
    from raico.plants.robots import load_robot
    from raico.stages.babble import BabbleConfig, babble, desired_trajectory

    cfg = BabbleConfig(plant="biorob", episodes=1, duration=2.0, dt=0.01, knots=8, substeps=10, amplitude=1.0)
    d = babble(cfg)
    robot = load_robot("biorob")
    spline = desired_trajectory(np.random.default_rng(cfg.seed), robot.default_q, robot.lower, robot.upper, cfg)
    assert close(d.q_des[0], spline(d.t), scale=1.0)   # radians
    tau = cfg.kp * (spline(d.t) - d.q[0]) + cfg.kd * (spline(d.t, 1) - d.qdot[0])
    u_max = robot.babble_torque_limit()
    assert np.allclose(d.u[0], np.clip(tau, -u_max, u_max), atol=1e-9)
    assert np.abs(d.u[0]).max() > 0.1  # the arm was driven, not at rest


@pytest.mark.parametrize("args, message", [
    (["--plant", "nope"], "unknown plant 'nope': choose one of pendulum, cartpole, arm5, biorob, nao"),
    (["--plant", "arm5", "--episodes", "0"], "episodes must be >= 1"),
    (["--plant", "arm5", "--dt", "-1"], "dt must be in (0, 0.1] s"),
])
def test_bad_input_one_line_nonzero_nothing_written(raico, tmp_path, args, message):
    res = raico("babble", *args, "--artifacts", tmp_path)
    assert res.exit_code == 2  # BadInput
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert lines == [f"raico: error: {message}"]
    assert not (tmp_path / "babble").exists() or not any((tmp_path / "babble").iterdir())


def test_console_script_usage_error_is_one_line(tmp_path):
    exe = Path(sys.executable).with_name("raico")
    p = subprocess.run([str(exe), "babble", "--artifacts", str(tmp_path), "--episodes"], capture_output=True, text=True)
    assert p.returncode == 2 and p.stderr.strip() == "raico: error: Option '--episodes' requires an argument."
    # no robot at all: babble needs a plant or a problem file, said in one line
    p = subprocess.run([str(exe), "babble", "--artifacts", str(tmp_path)], capture_output=True, text=True)
    assert p.returncode == 2 and p.stderr.strip() == ("raico: error: unknown plant '': choose one of pendulum, cartpole, "
                                                      "arm5, biorob, nao (or --problem FILE)")


def test_sigkill_halfway_leaves_nothing_valid_and_next_run_completes(raico, tmp_path):
    exe = Path(sys.executable).with_name("raico")
    cmd = [str(exe), "babble", "--plant", "arm5", "--episodes", "40", "--quiet", "--no-record",
           "--artifacts", str(tmp_path)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.time() + 60
    while time.time() < deadline and not list((tmp_path / "babble").glob(".tmp-*")):
        time.sleep(0.05)
    time.sleep(0.5)
    assert proc.poll() is None, "the run ended before it could be killed"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert [e for e in Cache(tmp_path).list("babble") if e.valid] == []
    ls = raico("ls", "--artifacts", tmp_path)
    assert ls.output.strip() == ""
    small = [str(exe), "babble", "--plant", "arm5", "--episodes", "1", "--quiet", "--no-record", "--json",
             "--artifacts", str(tmp_path)]
    done = subprocess.run(small, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.splitlines()[-1])["status"] == "ok"
    assert not list((tmp_path / "babble").glob(".tmp-*"))
    assert len([e for e in Cache(tmp_path).list("babble") if e.valid]) == 1


@pytest.mark.parametrize("plant", ["pendulum", "arm5", "biorob", "nao"])
def test_babble_recording_has_a_world_transform_for_every_body(raico, tmp_path, plant):
    from rerun.chunk import RrdReader

    from raico.plants.robots import shared_robot

    res = raico("babble", "--plant", plant, "--episodes", 1, "--duration", 0.1, "--json", "--artifacts", tmp_path)
    assert res.exit_code == 0, res.output
    folder = Path(json.loads(res.stdout.strip().splitlines()[-1])["path"])
    chunks = RrdReader(folder / "recording.rrd").stream().to_chunks()
    timed = {c.entity_path for c in chunks if "sim_time" in c.timeline_names}
    robot = shared_robot(plant)
    from pydrake.multibody.tree import BodyIndex

    from raico.pipeline.recordings.rerun_io import entity_name

    bodies = [entity_name(robot.plant.get_body(BodyIndex(i)).name()) for i in range(1, robot.plant.num_bodies())]
    assert len(bodies) == robot.plant.num_bodies() - 1 >= {"pendulum": 2, "arm5": 5, "biorob": 5, "nao": 31}[plant]
    for b in bodies:
        assert f"/world/robot/{b}" in timed, b
    rows = sum(c.num_rows for c in chunks if c.entity_path == f"/world/robot/{bodies[-1]}"
               and "sim_time" in c.timeline_names)
    assert rows == 51  # 0.1 s at 2 ms, both ends
