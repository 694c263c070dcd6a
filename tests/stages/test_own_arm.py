"""What a user with their own arm meets: a six-joint arm on a prismatic lift (tests/data/lift6.urdf, its
visuals ``package://`` meshes, one of them missing, every joint damped) through babble, learn and evaluate.

- learn and evaluate judge "task achieved" as execute does (one function, per term in its unit);
- babbling works in each joint's units (m and N on the lift) and stays inside every joint range;
- the model file's load notes are said once per learn loop."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).resolve().parents[1] / "data"
PROBLEM = DATA / "lift6_reach.toml"
NOTE = "raico: note: lift6.urdf: "

# execute's verdict of an execution that missed its reach by 1.57 cm (the case learn called achieved: its
# 5 cm tolerance was not execute's 1 cm)
MISSED = {"achieved": False, "worst": "reach", "kind": "position", "unit": "m", "error": 0.0157, "tol": 0.01}
WITHIN = {"achieved": True, "worst": "bend", "kind": "posture", "unit": "rad", "error": 0.03, "tol": 0.05}


def cli(*args):
    from typer.testing import CliRunner

    from raico.pipeline.interface.cli import app

    return CliRunner().invoke(app, [str(a) for a in args])


def last_json(res) -> dict:
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------ one judgement of "task achieved"
def test_learn_judges_an_episode_as_execute_does():
    from raico.stages.evaluate.metrics import executed_task, task_note
    from raico.stages.learn import episode_task, task_words

    v = episode_task(None, float("nan"), {"task": MISSED}, "ok")
    assert v == executed_task(MISSED, "ok") and v["achieved"] is False
    assert task_words(v) == "task missed: worst term 'reach' 0.0157 m > 0.01 m (position)"
    # terms within their tolerances but the execution lost its plan: missed, and the line says why
    lost = episode_task(None, float("nan"), {"task": WITHIN}, "tracking-lost")
    assert lost["achieved"] is False and task_note(lost) == (
        "task missed: worst term 'bend' 0.03 rad <= 0.05 rad (posture), status tracking-lost")
    assert episode_task(None, float("nan"), {"task": WITHIN}, "ok")["achieved"] is True
    assert episode_task(None, float("nan"), {}, "ok") is None and task_words(None) == "no task term to judge"
    # a task's own criterion ([achieved]: the pendulum's end angle) is judged as before, in rad
    crit = {"joint": "theta", "angle": np.pi, "tol": 0.1}
    up = episode_task(crit, np.pi + 0.05 - 2 * np.pi, {"task": MISSED}, "tracking-lost")
    assert up["achieved"] is True and up["unit"] == "rad" and up["error"] == pytest.approx(0.05, rel=1e-9)
    assert episode_task(crit, np.pi, {}, "fell")["achieved"] is False


def test_evaluate_names_the_worst_term_in_its_unit_not_a_mixed_maximum():
    from raico.pipeline.engine.runner import evaluation_notes
    from raico.stages.evaluate.metrics import executed_task

    m = {"final_cost": 2.0, "via_point_errors": {"bend@50": 1.01, "reach@50": 0.004},
         "task": WITHIN, "executed_via_point_errors": {"bend@50": 0.03, "reach@50": 0.0157},
         "executed_task": executed_task(MISSED, "ok")}
    notes = evaluation_notes(m)
    assert notes == ["final cost 2", "planned task achieved: worst term 'bend' 0.03 rad <= 0.05 rad (posture)",
                     "executed task missed: worst term 'reach' 0.0157 m > 0.01 m (position)"]
    assert not any("1.01" in n for n in notes)


@pytest.fixture(scope="module")
def lift_learn(tmp_path_factory):
    """Two learn episodes on the lift arm (small settings), its stderr and artifacts."""
    art = tmp_path_factory.mktemp("lift") / "art"
    res = cli("learn", "--problem", PROBLEM, "--episodes", 2, "--babble-points", 40, "--iterations", 5,
              "--stride", 5, "--restarts", 0, "--json", "--artifacts", art)
    return res, last_json(res), art


def test_learn_reports_execute_s_verdict_of_every_episode(lift_learn):
    from raico.stages.evaluate.metrics import executed_task, task_note

    res, line, art = lift_learn
    doc = json.loads((Path(line["path"]) / "episodes.json").read_text())
    # each episode's summary ("learn episode K/N: ..."), not the loop's other lines (a random episode run instead)
    said = [ln for ln in res.stderr.splitlines() if re.match(r"learn episode \d+/\d+:", ln)]
    assert len(doc["episodes"]) == len(said) == 2
    for ep, words in zip(doc["episodes"], said):
        meta = json.loads((art / "execute" / ep["execute"] / "meta.json").read_text())
        verdict = executed_task(meta["metrics"]["task"], meta["status"])
        assert ep["achieved"] == verdict["achieved"] and ep["task_error"] == verdict["error"]
        assert ep["task_unit"] == "m" and task_note(verdict) in words
    assert line["metrics"]["achieved"] == [ep["achieved"] for ep in doc["episodes"]]


def test_learn_says_the_model_file_s_load_notes_once(lift_learn):
    res, _, _ = lift_learn
    notes = [ln for ln in res.stderr.splitlines() if ln.startswith(NOTE)]
    assert any("<collision> elements dropped" in n for n in notes)
    assert any("mesh file missing (package://lift6_description/meshes/hand.stl)" in n for n in notes)
    assert len(notes) == len(set(notes)), res.stderr   # once per loop, not once per episode


def test_evaluate_stores_execute_s_verdicts(lift_learn):
    from raico.stages.evaluate.metrics import executed_task

    _, line, art = lift_learn
    ep = json.loads((Path(line["path"]) / "episodes.json").read_text())["episodes"][-1]
    res = cli("evaluate", "--plan", ep["plan"], "--rollout", ep["execute"], "--json", "--artifacts", art)
    ev = last_json(res)["metrics"]
    meta = json.loads((art / "execute" / ep["execute"] / "meta.json").read_text())
    plan = json.loads((art / "plan" / ep["plan"] / "meta.json").read_text())
    assert ev["executed_task"] == executed_task(meta["metrics"]["task"], meta["status"])
    assert ev["task"] == plan["metrics"]["task"]
    assert "executed task " in res.stderr and " m (position)" in res.stderr


# ------------------------------------------------------------------ babbling in each joint's units
def test_the_random_torques_are_capped_at_what_the_pd_holds_inside_the_margin():
    from raico.stages.babble import MARGIN, BabbleConfig, noise_bound

    cfg = BabbleConfig(problem=str(PROBLEM), torque_noise=0.1)
    kp = np.array([1000.0, 50.0])
    bound = noise_bound(np.array([300.0, 40.0]), kp, np.array([0.0, -2.8]), np.array([0.4, 2.8]), cfg)
    # the lift: 30 N of noise would hold it 3 cm off its desired position; the cap keeps it at half the 2 cm margin
    assert bound[0] == pytest.approx(0.5 * 1000.0 * MARGIN * 0.4) and bound[1] == pytest.approx(4.0)
    assert np.all(bound / kp <= 0.5 * MARGIN * np.array([0.4, 5.6]) * (1 + 1e-9))   # rounding of min()


def test_babbling_a_lift_stays_inside_every_joint_range_in_its_own_units():
    from raico.planning.problem_file import read_problem
    from raico.plants.model_file import shared_model
    from raico.stages.babble import babble, joint_amplitudes, joint_gains
    from raico.stages.evaluate.metrics import prismatic_joints
    from raico.stages.learn import LearnConfig

    cfg = LearnConfig(problem=str(PROBLEM), babble_points=120).normalized().babble_config().normalized()
    robot = shared_model(read_problem(PROBLEM).robot_spec())
    lift = prismatic_joints(robot)
    kp, kd = joint_gains(lift, cfg)
    assert kp[0] == cfg.kp_prismatic and kd[0] == cfg.kd_prismatic and np.all(kp[1:] == cfg.kp)
    assert joint_amplitudes(lift, cfg).tolist() == [cfg.amplitude_prismatic] + [cfg.amplitude] * 5
    data = babble(cfg)
    q = data.q.reshape(-1, robot.n_q)
    assert np.all(q >= robot.lower) and np.all(q <= robot.upper), (q.min(axis=0), q.max(axis=0))
    assert q[:, 0].std() > 0.02 and np.all(q[:, 1:].std(axis=0) > 0.1)   # every joint moves (m, rad)


def test_q0_std_is_per_joint_type():
    """The start's spread: ``q0_std`` rad on the revolute joints, ``q0_std_prismatic`` m on the lift (the same
    normal draws, each scaled in its joint's unit)."""
    from raico.planning.problem_file import read_problem
    from raico.plants.model_file import shared_model
    from raico.stages.learn import LearnConfig
    from raico.stages.plan.stage import initial_posture

    robot = shared_model(read_problem(PROBLEM).robot_spec())
    z = np.random.default_rng(4).standard_normal(robot.n_q)
    q0 = initial_posture(robot, 0.1, 4, q0_std_prismatic=0.01)
    expected = np.clip(robot.default_q + np.r_[0.01, np.full(5, 0.1)] * z, robot.lower, robot.upper)
    np.testing.assert_array_equal(q0, expected)   # the lift spread by 0.01 m, not by 0.1 "rad"
    plan = LearnConfig(problem=str(PROBLEM), q0_std=0.1, q0_std_prismatic=0.01).plan_config(model="x", warm_start=None)
    assert (plan.q0_std, plan.q0_std_prismatic) == (0.1, 0.01)


def test_tracking_is_lost_in_each_joint_s_unit():
    """An execution's tracking-lost threshold: 0.5 rad on a revolute joint, 0.1 m on the lift (0.5 m would be
    more than its whole 0.4 m range); the reason names the joint in its unit."""
    from types import SimpleNamespace

    from raico.planning.problem_file import read_problem
    from raico.plants.model_file import shared_model
    from raico.stages.evaluate.metrics import TRACKING_LOST_M, execution_metrics

    robot = shared_model(read_problem(PROBLEM).robot_spec())
    K, n = 11, robot.n_q
    X_plan = np.tile(np.concatenate([robot.default_q, np.zeros(n)]), (K, 1))
    no_terms = SimpleNamespace(state_terms=[], T=K - 1)

    def status(joint: int, off: float) -> dict:
        X = X_plan.copy()
        X[6:, joint] += off
        return execution_metrics(no_terms, X, X_plan, np.zeros((K - 1, n)), robot, 0.01, np.zeros((K - 1, n), bool))

    lost = status(0, 1.5 * TRACKING_LOST_M)
    assert lost["status"] == "tracking-lost" and lost["failure_time"] == pytest.approx(0.06, rel=1e-9)
    assert "lift 0.15 m from its plan" in lost["reason"] and lost["thresholds"]["tracking_lost_m"] == TRACKING_LOST_M
    assert status(0, 0.5 * TRACKING_LOST_M)["status"] == "ok"
    assert status(2, 0.3)["status"] == "ok"   # 0.3 rad on the shoulder: within 0.5 rad
    assert "shoulder 0.60 rad" in status(2, 0.6)["reason"]
