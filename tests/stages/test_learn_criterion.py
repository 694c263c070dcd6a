"""The learning loop's success criterion on synthetic end states, and its recovery when an episode's
execution gives no data."""

from __future__ import annotations

import json

import numpy as np
import pytest

from raico.stages.learn import own_criterion

UPRIGHT = {"joint": "pole", "angle": np.pi, "tol": 0.1, "velocity_tol": 1.0}


@pytest.mark.parametrize("q_end, v_end, status, achieved", [
    (np.pi, 0.0, "ok", True),
    (np.pi + 0.09, -0.9, "ok", True),                # within both tolerances
    (np.pi + 6 * np.pi, 0.2, "ok", True),            # three turns later: the angle is wrapped
    (np.pi - 0.05, 3.0, "ok", False),                # passing upright at 3 rad/s is not balanced
    (np.pi + 0.11, 0.0, "ok", False),                # still, 0.11 rad off
    (np.pi, 0.0, "diverged", False),
    (np.pi, 0.0, "tracking-lost", True),             # ended upright though it left its plan
    (np.nan, 0.0, "ok", False),
    (np.pi, np.nan, "ok", False),
])
def test_upright_needs_angle_and_speed(q_end, v_end, status, achieved):
    v = own_criterion(UPRIGHT, q_end, status, v_end)
    assert v["achieved"] is achieved
    assert v["kind"] == "end angle and speed" and v["velocity_tol"] == 1.0


def test_without_a_speed_tolerance_the_end_angle_alone_judges():
    crit = {k: UPRIGHT[k] for k in ("joint", "angle", "tol")}
    v = own_criterion(crit, np.pi, "ok", 3.0)
    assert v["achieved"] and v["kind"] == "end angle" and v["velocity_tol"] is None


def test_problem_file_reads_velocity_tol_and_refuses_a_bad_one():
    from raico.planning.problem_file import read_achieved

    assert read_achieved({"joint": "pole", "angle": 3.14, "tol": 0.1, "velocity_tol": 1})["velocity_tol"] == 1.0
    assert "velocity_tol" not in read_achieved({"joint": "pole", "angle": 3.14, "tol": 0.1})
    with pytest.raises(ValueError, match="velocity_tol"):
        read_achieved({"joint": "pole", "angle": 3.14, "tol": 0.1, "velocity_tol": 0})


def test_an_episode_without_data_is_followed_by_a_random_episode(tmp_path, monkeypatch):
    """The first episode's execution is made to give no data (as a diverged plan's does): a random episode
    with its own seed joins the next fit, and its seconds count as executed."""
    from typer.testing import CliRunner

    import raico.stages.learn as learn
    from raico.pipeline.interface.cli import app

    real = learn.episode_measurements

    def first_without_data(cfg, robots, fit, plan, execution, heldout=None):
        m = real(cfg, robots, fit, plan, execution, heldout)
        return {**m, "data_steps": 0} if fit.metrics["n_points"] == cfg.babble_points else m

    monkeypatch.setattr(learn, "episode_measurements", first_without_data)
    res = CliRunner().invoke(app, ["learn", "--plant", "pendulum", "--task", "swing-up", "--episodes", "2",
                                   "--iterations", "2", "--restarts", "0", "--stride", "25", "--no-record", "--json",
                                   "--artifacts", str(tmp_path)])
    assert res.exit_code == 0, res.output
    m = json.loads(res.stdout.strip().splitlines()[-1])["metrics"]
    babble_s = m["babble_seconds"]
    assert m["random_seconds"][0] == babble_s and m["random_seconds"][1] == 0.0
    assert m["executed_seconds"][0] == pytest.approx(m["executed_seconds"][1] + babble_s)
    # the second fit: the babbling, the first execution (nothing usable: the execute stage's own data are
    # still read by the fit, every 25th step) and the random episode's samples
    assert m["n_points"][1] > 2 * m["n_points"][0] - 1
    assert "a random" in res.stderr and "episode executed instead" in res.stderr
    babbles = list((tmp_path / "babble").iterdir())
    assert len(babbles) == 3   # the babbling, the held-out babbling and the random episode
