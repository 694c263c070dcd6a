"""Execution on the free-standing Nao and on the discrete arm: standing, falling, limits,
diverged plans, statuses (real Drake, small horizons)."""

import math

import numpy as np
import pytest

from raico.plants.robots import builtin_spec, shared_robot
from raico.stages.evaluate.metrics import CONTACT_TOL, LIMIT_TOL
from raico.stages.execute.config import ExecuteConfig
from raico.stages.execute.stage import execute

LIMIT_SLACK = LIMIT_TOL  # rad: Drake's SAP limit constraints are stiff but compliant


def pseudo_plan(Q: np.ndarray, dt: float) -> dict:
    """A pseudo-dynamics plan through joint postures ``Q (T+1, n)``: semi-implicit Euler velocities
    and accelerations, and the feedback ``u = a + 100 (q_plan - q) + 20 (v_plan - v)``."""
    V = np.vstack([np.zeros(Q.shape[1]), np.diff(Q, axis=0) / dt])
    U = np.diff(V, axis=0) / dt
    n, T = Q.shape[1], len(U)
    O = np.tile(np.hstack([-100 * np.eye(n), -20 * np.eye(n)]), (T, 1, 1))
    X = np.hstack([Q, V])
    o = U - np.einsum("tij,tj->ti", O, X[:-1])
    return {"X": X, "U": U, "o": o, "O": O}


def desc_for(plant: str, q0: np.ndarray, T: int, dt: float) -> dict:
    return {"plant": plant, "task": "test", "dt": dt, "T": T, "q0": q0.tolist(),
            "x0": np.r_[q0, 0 * q0].tolist(), "control_kind": "acceleration", "terms": []}


def assert_within_limits(X: np.ndarray, robot) -> None:
    Q = X[:, :robot.n_q]
    assert np.all(np.isfinite(Q))
    assert np.all(Q >= robot.lower - LIMIT_SLACK) and np.all(Q <= robot.upper + LIMIT_SLACK)


@pytest.mark.numerics
def test_free_nao_stands_still_in_the_default_posture():
    nao = shared_robot("nao")
    T, dt = 300, 0.01
    Q = np.tile(nao.default_q, (T + 1, 1))
    out = execute(ExecuteConfig(plan="hold"), desc_for("nao", nao.default_q, T, dt), pseudo_plan(Q, dt))
    m, d = out.metrics, out.floating
    assert (m["status"], m["stood"], m["failure_time"], m["start_tilt"]) == ("ok", True, None, 0.0)
    # the feet carry the robot's weight; the default posture leans over the left leg, whose sole
    # takes (nearly) all of it, the right sole touches the ground
    assert np.allclose(d["sole_force"][1:].sum(axis=1), 5.305354 * 9.81, rtol=0.02)
    assert np.all(d["sole_force"][1:, 0] > 0.95 * 5.305354 * 9.81)
    # it stays where it was put: torso, CoG and every sole corner within 1 mm
    assert np.abs(d["torso_p"] - d["torso_p"][0]).max() < 1e-3
    assert np.abs(d["cog"] - d["cog"][0]).max() < 1e-3
    assert np.abs(d["corners"][..., 2]).max() < CONTACT_TOL
    assert m["max_tracking_error"] < 1e-3 and m["cog_inside_fraction"] == 1.0
    # the controller's command (the PD law at each step's end state plus the feed-forward), clamped, is the
    # torque Drake applied: what the limits status judges is what the motors were asked
    from raico.plants.floating import shared_floating

    free = shared_floating(builtin_spec("nao"))
    np.testing.assert_allclose(np.clip(d["torque_asked"], -free.effort, free.effort) @ free.A, out.tau, atol=1e-6)
    assert np.abs(out.tau).max() > 0.1 and m["effort_clamped_fraction"] == 0.0
    # the contact polygon: all eight sole corners (both feet), the CoG well inside
    assert np.isfinite(d["support"]).all(axis=2).sum(axis=1).min() >= 4
    assert m["cog_min_margin"] > 0.03
    assert_within_limits(out.X, nao)


@pytest.mark.numerics
def test_free_nao_falls_when_the_plan_pushes_the_cog_outside_the_feet():
    """The fixed-base plan tilts the robot over its left ankle until the CoG is 5 cm outside the
    left sole (the welded model does not mind); the free robot falls."""
    from raico.plants.taskmaps import CenterOfMass

    nao = shared_robot("nao")
    T, dt = 200, 0.01
    j = nao.joint_names.index("LAnkleRoll")
    s = np.clip(np.arange(T + 1) / 100, 0, 1)
    Q = np.tile(nao.default_q, (T + 1, 1))
    Q[:, j] += 0.45 * (3 * s ** 2 - 2 * s ** 3)
    cog, _ = CenterOfMass(nao).values_and_jacobians(Q)
    assert cog[-1, 1] > 0.044 + 0.045  # the left sole's outer edge is at y = 0.044 m
    out = execute(ExecuteConfig(plan="lean"), desc_for("nao", nao.default_q, T, dt), pseudo_plan(Q, dt))
    m = out.metrics
    assert m["status"] == "fell" and m["stood"] is False
    assert 0.2 < m["failure_time"] < T * dt and m["reason"].startswith(f"fell at t = {m['failure_time']:.3g} s")
    k = int(round(m["failure_time"] / dt))
    flags = m["fall_conditions"]
    assert min(t for t in flags.values() if t is not None) == m["failure_time"]
    # at the moment of failure the executed CoG has left the contact polygon
    assert out.floating["cog_margin"][k] < 0
    assert m["cog_inside_fraction"] < 1.0
    assert_within_limits(out.X, nao)


@pytest.mark.numerics
def test_diverged_plan_is_not_reported_ok():
    nao = shared_robot("nao")
    T, dt = 20, 0.01
    plan = pseudo_plan(np.tile(nao.default_q, (T + 1, 1)), dt)
    out = execute(ExecuteConfig(plan="p"), desc_for("nao", nao.default_q, T, dt), plan, plan_status="diverged")
    m = out.metrics  # the same hold-still plan stands (test above), but a diverged plan is marked so
    assert (m["status"], m["reason"], m["stood"]) == ("diverged", "the plan diverged (executed: ok)", False)
    bad = {**plan, "X": np.where(np.arange(T + 1)[:, None] > 10, np.nan, plan["X"])}
    out = execute(ExecuteConfig(plan="p"), desc_for("nao", nao.default_q, T, dt), bad, plan_status="max-iterations")
    assert (out.metrics["status"], out.metrics["reason"]) == ("diverged", "the plan is not finite: not executed")
    assert not np.isfinite(out.X).any() and out.tau.shape == (T, nao.n_q)
    assert all(math.isinf(v) for v in out.metrics["via_point_errors"].values())


@pytest.mark.numerics
def test_arm_execution_enforces_joint_limits_and_reports_them():
    """A plan that turns the arm's forearm roll 0.3 rad past its upper limit (pi): the discrete plant
    stops it at the limit, the other joints follow the plan, and the execution says ``limits``."""
    arm = shared_robot("arm5")
    T, dt = 500, 0.002
    j = arm.joint_names.index("forearm_roll")
    s = np.clip(np.arange(T + 1) / 350, 0, 1)
    Q = np.tile(arm.default_q, (T + 1, 1))
    Q[:, j] += (arm.upper[j] + 0.3 - arm.default_q[j]) * (3 * s ** 2 - 2 * s ** 3)
    out = execute(ExecuteConfig(plan="p"), desc_for("arm5", arm.default_q, T, dt), pseudo_plan(Q, dt))
    m = out.metrics
    assert_within_limits(out.X, arm)
    assert out.X[-1, j] == pytest.approx(arm.upper[j], abs=LIMIT_SLACK)
    # held at the limit: within LIMIT_TOL of it while the plan is more than LIMIT_TOL beyond
    held = np.mean((out.X[:, j] >= arm.upper[j] - LIMIT_TOL) & (Q[:, j] - out.X[:, j] > LIMIT_TOL))
    assert m["status"] == "limits" and m["position_limit_fraction"] == pytest.approx(held) and held > 0.2
    assert m["reason"] == (f"at a joint or effort limit in {m['limits_fraction']:.0%} of the samples (> 20%): "
                           f"forearm_roll position {held:.0%}")
    assert set(m["limited_joints"]) == {"forearm_roll"}
    others = [i for i in range(arm.n_q) if i != j]
    assert np.abs(out.X[:, others] - Q[:, others]).max() < 0.05


@pytest.mark.numerics
def test_open_loop_integration_matches_heun_and_measures_the_other_schemes():
    """Appendix C's integration check: the planned accelerations held per step, open loop, on Drake's continuous
    arm through computed torque: Drake's trajectory is Heun's pseudo-dynamics rollout (exact for a held
    acceleration) to round-off, and backward Euler's / Euler's drift by dt/2 times the velocity change."""
    from raico.plants.dynamics import PseudoDynamics, rollout

    arm = shared_robot("arm5")
    T, dt, n = 200, 0.002, arm.n_q
    t = np.arange(T) * dt
    U = np.stack([1.5 * np.sin(2 * np.pi * t / (T * dt) + k) for k in range(n)], axis=1)  # rad/s^2
    x0 = np.r_[arm.default_q, np.zeros(n)]
    errs = {}
    for scheme in ("heun", "backward-euler", "euler"):
        X = rollout(PseudoDynamics(n, dt, scheme), x0, U)
        plan = {"X": X, "U": U, "o": np.full_like(U, np.nan), "O": np.full((T, n, 2 * n), np.nan)}
        out = execute(ExecuteConfig(plan="p", open_loop=True), desc_for("arm5", arm.default_q, T, dt), plan)
        assert out.metrics["status"] == "ok" and np.all(np.isfinite(out.X))
        assert np.allclose(out.U, U)  # the planned controls themselves, no feedback (o, O not even finite)
        errs[scheme] = np.abs(out.X[:, :n] - X[:, :n]).max(axis=0)
    assert errs["heun"].max() < 1e-8
    drift = dt / 2 * np.abs(U.sum(axis=0) * dt)  # |q_scheme - q_exact| at the end: dt/2 |v_T - v_0|
    for scheme in ("backward-euler", "euler"):
        assert errs[scheme].max() > 1e-5 and np.all(errs[scheme] >= drift - 1e-8)
    with pytest.raises(ValueError, match="no x0-noise or process-noise"):
        ExecuteConfig(plan="p", open_loop=True, x0_noise=0.01).validate()
    with pytest.raises(ValueError, match="a floating robot stands on its feet"):
        execute(ExecuteConfig(plan="p", open_loop=True), desc_for("nao", shared_robot("nao").default_q, 2, 0.01),
                {"X": np.zeros((3, 50)), "U": np.zeros((2, 25))})


def test_the_ground_half_space_warning_is_dropped_and_nothing_else():
    """Drake warns once per process, at the first contact query, that a rigid half space has no deformable
    contact (raico has no deformable bodies): a fresh process that builds and simulates the free Nao prints
    nothing of it, while another Drake warning still gets through."""
    import subprocess
    import sys
    from pathlib import Path

    script = ("import logging\n"
              "from pydrake.systems.analysis import Simulator\n"
              "from pydrake.systems.framework import DiagramBuilder\n"
              "from raico.plants.floating import load_floating\n"
              "from raico.plants.robots import builtin_spec\n"
              "nao = load_floating(builtin_spec('nao'), DiagramBuilder(), time_step=1e-3)\n"
              "Simulator(nao.builder.Build()).AdvanceTo(0.01)\n"
              "logging.getLogger('drake').warning('another drake warning')\n")
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                         cwd=Path(__file__).resolve().parents[2])
    assert run.returncode == 0, run.stderr
    assert "half spaces" not in run.stderr
    assert "another drake warning" in run.stderr


@pytest.mark.numerics
def test_a_motor_that_only_clamps_the_noise_is_not_the_controllers_limit():
    """The arm holding its default posture under 15 N m of process noise: the 10 and 20 N m motors of the
    wrist and forearm clamp the noise in most steps (the light wrist is thrown about: tracking is lost), while
    the controller's own command stays inside every limit. The clamping is reported
    (``effort_clamped_fraction``), not counted as the controller at a limit."""
    arm = shared_robot("arm5")
    T, dt = 100, 0.002
    Q = np.tile(arm.default_q, (T + 1, 1))
    desc, plan = desc_for("arm5", arm.default_q, T, dt), pseudo_plan(Q, dt)
    quiet, noisy = (execute(ExecuteConfig(plan="p", process_noise=w, seed=2), desc, plan) for w in (0.0, 15.0))
    assert quiet.metrics["effort_clamped_fraction"] == 0.0 and noisy.metrics["effort_clamped_fraction"] > 0.5
    for out in (quiet, noisy):
        assert not out.effort_at_limit.any()
        assert not any("effort" in sh and sh["effort"] > 0 for sh in out.metrics["limited_joints"].values())
    assert np.abs(noisy.tau).max(axis=0)[-1] == pytest.approx(arm.effort[-1])  # the wrist's motor did clamp


@pytest.mark.numerics
def test_a_model_file_that_says_how_it_stands_executes_floating_as_the_nao():
    """Floating execution is the facts' (feet, sole, stand), not the Nao's name: its model file with those
    facts and no built-in name (a user's model file, stored in the plan as its spec) stands as the built-in
    Nao does, with the same numbers."""
    from raico.plants.model_file import RobotSpec

    nao = shared_robot("nao")
    T, dt = 30, 0.01
    Q = np.tile(nao.default_q, (T + 1, 1))
    desc = desc_for("nao", nao.default_q, T, dt)
    spec = RobotSpec.from_dict({**builtin_spec("nao").to_dict(), "plant": None})
    builtin = execute(ExecuteConfig(plan="hold"), desc, pseudo_plan(Q, dt))
    own = execute(ExecuteConfig(plan="hold"), {**desc, "plant": "own", "robot": spec.to_dict()}, pseudo_plan(Q, dt))
    assert own.metrics["status"] == builtin.metrics["status"] == "ok" and own.metrics["stood"]
    np.testing.assert_array_equal(own.X, builtin.X)
    np.testing.assert_array_equal(own.floating["corners"], builtin.floating["corners"])
