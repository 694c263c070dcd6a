"""A moving target in a problem file (``moving``): one via-point per step, each on the circle (or line) at its
step's time, its name the term's with the step; bad forms refused in one line."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from raico.planning.problem_terms import moving_offset

ROOT = Path(__file__).resolve().parents[2]
TRACK = ROOT / "raico/problems/examples/xarm7_track.toml"


def _short(tmp_path, moving: str | None = None) -> Path:
    src = TRACK.read_text().replace("T = 200", "T = 20").replace("from = 10, to = 199", "from = 4, to = 20")
    if moving is not None:
        src = src.replace("moving = { radius = 0.05, period = 1.0, axes = [1, 2] }", moving)
    path = tmp_path / "track.toml"
    path.write_text(src)
    return path


@pytest.mark.numerics
def test_moving_offset_is_a_circle_from_its_start_plus_a_line():
    m = {"radius": 0.05, "period": 1.0, "axes": [1, 2], "phase": 0.3, "velocity": [0.1, 0.0, 0.0]}
    assert np.array_equal(moving_offset(m, 0.0), np.zeros(3))
    for t in (0.1, 0.37, 0.9):
        off = moving_offset(m, t)
        assert math.isclose(off[0], 0.1 * t, rel_tol=1e-9)
        centre = -0.05 * np.array([math.cos(0.3), math.sin(0.3)])   # the circle's centre from its start
        assert math.isclose(np.linalg.norm(off[1:] - centre), 0.05, rel_tol=1e-9)


@pytest.mark.numerics
def test_a_moving_target_is_one_via_point_per_step_on_the_path(tmp_path):
    from raico.planning.costs import ViaPoint
    from raico.stages.plan.stage import PlanConfig, build_problem

    pb = build_problem(PlanConfig(problem=str(_short(tmp_path)), dynamics="analytic", q0_std=0.0))[2]
    track = [t for t in pb.state_terms if isinstance(t, ViaPoint) and t.name.startswith("track")]
    assert [t.name for t in track] == [f"track_t{s}" for s in range(4, 21)]
    start = track[0].target - moving_offset({"radius": 0.05, "period": 1.0, "axes": [1, 2], "phase": 0.0}, 0.04)
    for s, term in zip(range(4, 21), track):
        assert list(np.flatnonzero(term.active(np.arange(pb.T + 1)))) == [s]
        off = term.target - start
        assert abs(off[0]) <= 1e-9 * np.abs(term.target).max()   # the path lies in y-z
        assert math.isclose(np.linalg.norm(off[1:] - [-0.05, 0.0]), 0.05, rel_tol=1e-9)


@pytest.mark.parametrize("moving, match", [
    ("moving = { radius = 0.05 }", "period"),
    ("moving = { radius = 0.05, period = 1.0, axes = [1, 1] }", "axes"),
    ("moving = { speed = 1.0 }", "speed"),
    ("moving = { velocity = [1.0, 2.0] }", "velocity"),
])
def test_bad_moving_targets_are_refused(tmp_path, moving, match):
    from raico.planning.problem_file import read_problem

    with pytest.raises(ValueError, match=match):
        read_problem(_short(tmp_path, moving))
