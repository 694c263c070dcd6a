"""The Rerun viewer renders recordings headless (raico/pipeline/recordings/screenshots.py): one babble recording
per plant shows the robot in frame; a plan recording opens on ``sim_time`` with its cost view drawn, and
shows the robot in the same pose on the ``iteration`` timeline as at the end of the motion.

Needs a Vulkan driver for the software renderer (`.ci/run` installs Debian's mesa-vulkan-drivers);
skipped, with the reason, where none is installed.
"""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from raico.pipeline.interface.cli import app
from raico.pipeline.recordings.screenshots import (
    content_mask,
    read_png,
    render_screenshot,
    renderer_unavailable,
    report_screenshots,
    robot_mask,
)

UNAVAILABLE = renderer_unavailable()
needs_renderer = pytest.mark.skipif(UNAVAILABLE is not None, reason=str(UNAVAILABLE))


def _run(*args) -> dict:
    res = CliRunner().invoke(app, [*map(str, args), "--json", "--quiet"])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout.strip().splitlines()[-1])


def _assert_in_frame(robot: np.ndarray) -> None:
    rows, cols = np.nonzero(robot)
    assert robot.mean() > 3e-4, f"no robot in the 3D view ({robot.mean():.5f} of its pixels)"
    # in frame: the robot's pixels do not hug the view's border
    assert rows.min() > 0 and cols.min() > 0 and rows.max() < robot.shape[0] - 1 and cols.max() < robot.shape[1] - 1


@pytest.mark.slow  # renders with the software Vulkan driver: 9-35 s
@needs_renderer
@pytest.mark.parametrize("plant", ["pendulum", "arm5", "biorob", "nao"])
def test_viewer_renders_the_robot(tmp_path, plant):
    line = _run("babble", "--plant", plant, "--episodes", 1, "--duration", 0.2, "--artifacts", tmp_path)
    shot, view = tmp_path / "shot.png", tmp_path / "robot.png"
    render_screenshot(line["recording"], shot, views={"robot": view})
    assert shot.exists() and read_png(shot).shape == (1080, 1920, 3)
    _assert_in_frame(robot_mask(read_png(view)))


@pytest.mark.slow  # renders with the software Vulkan driver: 9-35 s
@needs_renderer
def test_plan_recording_shows_cost_and_robot_on_both_timelines(tmp_path):
    line = _run("plan", "--plant", "pendulum", "--task", "swing-up", "--solver", "ilqg", "--iterations", 3,
                "--artifacts", tmp_path)
    rrd = line["recording"]
    cost = "log10 cost per iteration"
    # as opened: sim_time, the cost bars drawn (coloured pixels in the cost view), the robot in frame
    render_screenshot(rrd, tmp_path / "open.png", views={"robot": tmp_path / "robot.png", cost: tmp_path / "cost.png"})
    bars = content_mask(read_png(tmp_path / "cost.png"))
    assert bars.mean() > 0.05, f"cost view nearly empty ({bars.mean():.3f} of its pixels coloured)"
    _assert_in_frame(robot_mask(read_png(tmp_path / "robot.png")))
    # the iteration timeline at the last iteration shows the plan's final pose, as sim_time does at the end
    # of the motion (its horizon, in s)
    from raico.planning.tasks import PENDULUM_T, TASKS

    last = int(line["metrics"]["iterations"])
    end_s = PENDULUM_T * TASKS[("pendulum", "swing-up")].dt
    render_screenshot(rrd, tmp_path / "end.png", timeline="sim_time", time=end_s, views={"robot": tmp_path / "r_end.png"})
    render_screenshot(rrd, tmp_path / "it.png", timeline="iteration", time=last, views={"robot": tmp_path / "r_it.png"})
    end, it = robot_mask(read_png(tmp_path / "r_end.png")), robot_mask(read_png(tmp_path / "r_it.png"))
    overlap = (end & it).sum() / max((end | it).sum(), 1)
    assert it.mean() > 3e-4 and overlap > 0.8, f"the robot on the iteration timeline is not at its final pose " \
                                                f"(IoU {overlap:.2f} with the end of sim_time)"
    # the report's screenshots: the latest plan of each plant in the cache
    from raico.pipeline.engine.cache import Cache

    shots = report_screenshots(Cache(tmp_path), tmp_path / "report")
    key = next(iter(Cache(tmp_path).list("plan"))).key
    assert [p.name for _, p in shots] == [f"plan-pendulum-{key}.png"] and shots[0][1].exists()
    assert "pendulum swing-up ilqg" in shots[0][0]
    # the same plan again: the picture is reused, no viewer is started
    from raico.pipeline.recordings import screenshots

    def no_viewer():
        raise AssertionError("a viewer was started for a plan that has its screenshot")

    before = shots[0][1].stat().st_mtime_ns
    import pytest

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(screenshots, "_viewer", no_viewer)
        again = report_screenshots(Cache(tmp_path), tmp_path / "report")
    assert again == shots and shots[0][1].stat().st_mtime_ns == before


def test_report_screenshots_without_plans_or_renderer(tmp_path, monkeypatch):
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.recordings import screenshots

    assert report_screenshots(Cache(tmp_path), tmp_path / "out") == []
    monkeypatch.setattr(screenshots, "renderer_unavailable", lambda: "no Vulkan driver")
    from types import SimpleNamespace

    plan = SimpleNamespace(key="0123456789abcdef", path=tmp_path, meta={"config": {}})
    monkeypatch.setattr(screenshots, "_latest_plans", lambda cache, stage="plan": {"arm5": plan})
    said = []
    assert report_screenshots(Cache(tmp_path), tmp_path / "out", said.append) == []
    # no renderer installed: no screenshots, nothing said (the report works without them); a cache that cannot be
    # listed and a viewer that does not start are said
    assert said == []

    def unreadable(cache, stage="plan"):
        raise PermissionError(13, "Permission denied", str(tmp_path / "plan"))

    monkeypatch.setattr(screenshots, "_latest_plans", unreadable)
    said.clear()
    assert report_screenshots(Cache(tmp_path), tmp_path / "out", said.append) == []
    assert len(said) == 1 and "the cache cannot be listed (PermissionError" in said[0] and "Permission denied" in said[0]
    monkeypatch.setattr(screenshots, "_latest_plans", lambda cache, stage="plan": {"arm5": plan})
    monkeypatch.setattr(screenshots, "renderer_unavailable", lambda: None)

    def no_start():
        raise RuntimeError("the Rerun viewer exited at start (code 102)")

    monkeypatch.setattr(screenshots, "_viewer", no_start)
    said.clear()
    assert report_screenshots(Cache(tmp_path), tmp_path / "out", said.append) == []
    assert said == ["raico: warning: screenshots left out of the report: the Rerun viewer did not start "
                    "(RuntimeError: the Rerun viewer exited at start (code 102))"]


def _plan_arm5(tmp_path, *extra) -> dict:
    return _run("plan", "--plant", "arm5", "--task", "reach", "--iterations", 2, *extra, "--artifacts", tmp_path)


@pytest.mark.slow  # renders with the software Vulkan driver: 9-35 s
@needs_renderer
def test_show_png_renders_a_recording_headless(tmp_path):
    """``raico show KEY --png OUT --time T`` and ``api.show_png``: the recording as the viewer opens it, the
    robot drawn in the 3D view (the left 60 % of the window, above the cost view)."""
    from raico.pipeline.interface import api

    key = _plan_arm5(tmp_path, "--no-record")["key"]   # the recording is written from the entry's data
    out = tmp_path / "shots" / "plan.png"
    res = CliRunner().invoke(app, ["show", key[:8], "--png", str(out), "--time", "0.5", "--artifacts", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert str(out) in res.stderr and not res.stdout
    img = read_png(out)
    assert img.shape == (1080, 1920, 3)
    assert robot_mask(img[60:780, :1150]).mean() > 3e-4
    again = api.show_png(key, tmp_path / "api.png", artifacts=tmp_path)
    assert again == tmp_path / "api.png" and robot_mask(read_png(again)[60:780, :1150]).mean() > 3e-4


def test_show_png_without_a_renderer_names_what_is_missing(tmp_path, monkeypatch):
    from raico.pipeline.errors import RaicoError
    from raico.pipeline.interface import api
    from raico.pipeline.recordings import screenshots

    key = _plan_arm5(tmp_path, "--no-record")["key"]
    monkeypatch.setattr(screenshots, "VULKAN_ICDS", str(tmp_path / "no-icd" / "*.json"))
    monkeypatch.setenv("VK_ICD_FILENAMES", "")
    out = tmp_path / "plan.png"
    res = CliRunner().invoke(app, ["show", key, "--png", str(out), "--artifacts", str(tmp_path)])
    assert res.exit_code == 1, res.output
    assert res.stderr.count("\n") == 1 and res.stderr.startswith("raico: error: cannot render ")
    assert res.stderr.rstrip().endswith("no Vulkan driver (apt-get install mesa-vulkan-drivers)"), res.stderr
    assert not out.exists()
    with pytest.raises(RaicoError, match="no Vulkan driver"):
        api.show_png(key, out, artifacts=tmp_path)
    # the viewer itself failing (a driver that does not work) is one line, too, never a transport traceback
    monkeypatch.setattr(screenshots, "renderer_unavailable", lambda: None)

    def broken(*args, **kwargs):
        raise ConnectionError("transport error")

    monkeypatch.setattr(screenshots, "render_screenshot", broken)
    res = CliRunner().invoke(app, ["show", key, "--png", str(out), "--artifacts", str(tmp_path)])
    assert res.exit_code == 1 and res.stderr.count("\n") == 1, res.output
    assert "the Rerun viewer failed (transport error)" in res.stderr
    for args, needle in ((["--png", "x.jpg"], "--png x.jpg: a .png file"), (["--time", "1"], "--time goes with --png"),
                         (["--png", "x.png", "--time", "-1"], "--time -1.0: a time in s"),
                         (["--png", "x.png", "--open"], "give --open or --png, not both")):
        res = CliRunner().invoke(app, ["show", key, *args, "--artifacts", str(tmp_path)])
        assert res.exit_code == 2 and needle in res.stderr, (args, res.output)


@needs_renderer
@pytest.mark.parametrize("plant, task, extra", [
    ("pendulum", "swing-up", ["--iterations", 3, "--restarts", 0, "--stride", 25]),
    ("biorob", "reach", ["--alpha", 2, "--iterations", 5, "--babble-points", 100, "--restarts", 0]),
])
@pytest.mark.slow  # renders with the software Vulkan driver: 9-35 s
def test_learn_recording_frames_the_robot_and_fills_its_views(tmp_path, plant, task, extra):
    """A learn recording as opened (episode timeline, last episode): the robot in frame and
    the GP error, distance and time views drawn; the report renders it too."""
    line = _run("learn", "--plant", plant, "--task", task, "--episodes", 2, *extra, "--artifacts", tmp_path)
    views = {"robot": tmp_path / "robot.png", "distance to the target (m)": tmp_path / "distance.png",
             "time per evaluation (s)": tmp_path / "time.png",
             "GP error on the next execution, log10 (rad/s^2)": tmp_path / "gp.png"}
    render_screenshot(line["recording"], tmp_path / "learn.png", views=views)
    _assert_in_frame(robot_mask(read_png(views["robot"])))
    for name in list(views)[1:]:
        drawn = content_mask(read_png(views[name])).mean()
        assert drawn > 0.002, f"view {name!r} nearly empty ({drawn:.4f} of its pixels coloured)"
    from raico.pipeline.engine.cache import Cache

    shots = report_screenshots(Cache(tmp_path), tmp_path / "report")
    assert f"learn-{plant}-{line['key']}.png" in [p.name for _, p in shots]
