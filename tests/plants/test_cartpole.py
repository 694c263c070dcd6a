"""The cart-pole (PILCO's benchmark) and underactuation: its facts, its dynamics against PILCO's closed form,
the motor-command and substep models' derivatives, and underactuated planning against the exact LQ optimum."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from raico.plants.dynamics import ActuatedDynamics, LinearDynamics, SubstepDynamics
from raico.plants.dynamics_registry import make_dynamics
from raico.plants.model_file import ModelError, RobotSpec, load_model
from raico.plants.numdiff import check_dynamics
from raico.plants.robots import builtin_spec, shared_robot
from tests.tolerance import assert_close

# PILCO's values (UCL-SML/pilco-matlab scenarios/cartPole/dynamics_cp.m, settings_cp.m)
L, M_POLE, M_CART, B_FRICTION, G, MAX_U = 0.5, 0.5, 0.5, 0.1, 9.82, 10.0


def pilco_accelerations(x: np.ndarray, v: np.ndarray, theta: np.ndarray, dtheta: np.ndarray,
                        f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(xddot, thetaddot)`` of dynamics_cp.m (theta 0 hanging down; m, kg, N; the textbook cart-pole with
    a uniform rod and viscous cart friction), typed from its equations."""
    m, Mc, l, b, g = M_POLE, M_CART, L, B_FRICTION, G
    s, c = np.sin(theta), np.cos(theta)
    xdd = (2 * m * l * dtheta ** 2 * s + 3 * m * g * s * c + 4 * f - 4 * b * v) / (4 * (Mc + m) - 3 * m * c ** 2)
    tdd = (-3 * m * l * dtheta ** 2 * s * c - 6 * (Mc + m) * g * s - 6 * (f - b * v) * c) \
        / (4 * l * (m + Mc) - 3 * m * l * c ** 2)
    return xdd, tdd


def test_cartpole_facts():
    """PILCO's force limit on the cart's motor, no motor on the pole, a rail range, PILCO's g."""
    robot = shared_robot("cartpole")
    assert robot.joint_names == ("cart", "pole")
    assert robot.underactuated and robot.actuated.tolist() == [0]
    assert robot.effort.tolist() == [MAX_U, 0.0]
    assert robot.B_act.shape == (2, 1) and robot.B_act[:, 0].tolist() == [1.0, 0.0]
    assert robot.S.tolist() == [[1.0], [0.0]]
    assert robot.lower[0] == -2.0 and robot.upper[0] == 2.0 and not np.isfinite(robot.upper[1])
    assert robot.plant.gravity_field().gravity_vector()[2] == -G
    assert builtin_spec("cartpole").to_dict()["unactuated"] == ["pole"]


def test_cartpole_dynamics_against_pilco_closed_form():
    """Drake's forward dynamics of the model file equal dynamics_cp.m's closed form (to rounding) at random
    states and forces: masses, length, inertia, friction, gravity and the angle's sign."""
    robot = shared_robot("cartpole")
    dyn = make_dynamics("analytic", robot, 0.01)
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = np.array([rng.uniform(-1.5, 1.5), rng.uniform(-np.pi, 2 * np.pi)])
        v = 3.0 * rng.standard_normal(2)
        f = rng.uniform(-MAX_U, MAX_U)
        got = dyn.qddot(q, v, np.array([f, 0.0]))
        want = pilco_accelerations(q[0], v[0], q[1], v[1], f)
        assert_close(got, np.array(want), scale=10.0)


def test_unactuated_joint_must_exist(tmp_path):
    spec = builtin_spec("cartpole")
    bad = RobotSpec.from_dict({**spec.to_dict(), "unactuated": ["pol"]})
    with pytest.raises(ModelError, match="unactuated: joint 'pol'"):
        load_model(bad)


@pytest.mark.parametrize("kind", ["analytic", "learned"])
def test_actuated_and_substep_models_linearize(kind):
    """The motor-command model (``B = B_tau S``) and the substepped one (the chain rule through its steps)
    against finite differences, at a rest state and a brisk one, on Drake's model and on a GP's."""
    from raico.plants.dynamics_registry import DYNAMICS

    robot = shared_robot("cartpole")
    spec = DYNAMICS[kind]
    inner = make_dynamics(kind, robot, 0.01, spec.example_params(robot) if spec.needs_params else None)
    X = np.array([[0.0, 0.0, 0.0, 0.0], [0.4, 2.5, -1.0, 3.0]])
    U = np.array([[1.0], [-7.0]])
    for model in (ActuatedDynamics(inner, robot.S), ActuatedDynamics(SubstepDynamics(inner, 10), robot.S)):
        assert model.n_u == 1 and model.n_x == 4
        check_dynamics(model, X, U).assert_passed()
        A, a, B = model.linearize_trajectory(X, U)
        for k in range(2):
            A1, a1, B1 = model.linearize(X[k], U[k])
            assert_close(A[k], A1)
            assert_close(B[k], B1)
            assert_close(a[k], a1, scale=float(np.abs(X[k]).max()))
            assert_close(A1 @ X[k] + a1 + B1 @ U[k], model.step(X[k], U[k]))


def test_substeps_equal_the_fine_model_held():
    """Ten substeps of 10 ms are ten steps of the 10 ms model under the held force."""
    robot = shared_robot("cartpole")
    fine = make_dynamics("analytic", robot, 0.01)
    coarse = SubstepDynamics(fine, 10)
    x, u = np.array([0.1, 0.5, 0.0, 1.0]), np.array([3.0, 0.0])
    y = x
    for _ in range(10):
        y = fine.step(y, u)
    assert coarse.dt == pytest.approx(0.1)
    assert_close(coarse.step(x, u), y)


# ----------------------------------------------------------------------------- underactuated LQ
def cartpole_lq(T: int = 30):
    """The cart-pole linearized about its upright rest (Drake's model, 0.05 s steps, force on the cart only)
    as a time-invariant LQ problem: a terminal state target, a running state cost and a control cost."""
    from raico.planning.costs import ControlCost, StateTarget
    from raico.planning.problem import Problem

    robot = shared_robot("cartpole")
    model = ActuatedDynamics(make_dynamics("analytic", robot, 0.05), robot.S)
    up = np.array([0.0, np.pi, 0.0, 0.0])
    A, a, B = model.linearize(up, np.zeros(1))
    dyn = LinearDynamics(A=A, a=a + A @ up - up, B=B, dt=0.05)   # in deviations from upright: x' = A x + B u
    terms = [StateTarget(np.zeros(4), times=None, weight=1.0, precision=np.array([1.0, 10.0, 0.1, 0.1]), name="run"),
             StateTarget(np.zeros(4), times=[T], weight=100.0, name="end")]
    return Problem(dyn, np.array([0.3, 0.2, 0.0, 0.0]), T, terms, [ControlCost(0.01)])


def riccati(pb) -> tuple[np.ndarray, np.ndarray]:
    """The exact optimum ``X (T+1, n)``, ``U (T, m)`` of an LQ problem by the discrete Riccati recursion
    (``x' = A x + a + B u``, costs ``1/2 x^T R_t x - r_t^T x + 1/2 u^T H u - h^T u``), typed here."""
    dyn, T = pb.dynamics, pb.T
    A, a, B = dyn.A, dyn.a, dyn.B
    R, r = pb.quadratize_states(np.zeros((T + 1, pb.n_x)))
    H, h = pb.quadratize_controls(np.zeros((T, pb.n_u)))
    V, v = R[T], r[T]   # cost-to-go 1/2 x^T V x - v^T x
    K, k = [None] * T, [None] * T
    for t in range(T - 1, -1, -1):
        Quu = H[t] + B.T @ V @ B
        Qux = B.T @ V @ A
        qu = h[t] + B.T @ (v - V @ a)
        K[t] = -np.linalg.solve(Quu, Qux)
        k[t] = np.linalg.solve(Quu, qu)
        Qxx = R[t] + A.T @ V @ A
        qx = r[t] + A.T @ (v - V @ a)
        V = Qxx + Qux.T @ K[t]
        v = qx - Qux.T @ k[t]
        V = 0.5 * (V + V.T)
    X, U = np.empty((T + 1, pb.n_x)), np.empty((T, pb.n_u))
    X[0] = pb.x0
    for t in range(T):
        U[t] = k[t] + K[t] @ X[t]
        X[t + 1] = A @ X[t] + a + B @ U[t]
    return X, U


@pytest.mark.parametrize("solver", ["aico", "ilqg"])
def test_underactuated_lq_matches_riccati(solver):
    """AICO and iLQG on the cart-pole's LQ version (one control, four states) find the exact optimum."""
    from raico.planning.solvers import solve

    pb = cartpole_lq()
    X_ref, U_ref = riccati(pb)
    assert pb.n_u == 1
    res = solve(pb, solver, {"iterations": 20})
    assert_close(res.U, U_ref, rel=1e-6)
    assert_close(res.X, X_ref, rel=1e-6)


def test_a_model_files_robot_states_its_unactuated_joints(tmp_path):
    """A user's problem file names the joints without a motor and g as the built-in cart-pole's file does:
    the planner's controls are then the motors' (one here)."""
    from raico.stages.plan.stage import PlanConfig, build_problem

    urdf = Path(__file__).resolve().parents[2] / "raico" / "plants" / "models" / "cartpole.urdf"
    (tmp_path / "cp.toml").write_text(f'''name = "own-cartpole"
[robot]
file = "{urdf}"
unactuated = ["pole"]
gravity = 9.82
end_effectors = {{ tip = "tip" }}
[horizon]
T = 10
dt = 0.05
[dynamics]
model = "analytic"
[costs.up]
type = "posture"
joints = ["pole"]
target = [3.0]
times = "last"
weight = 10.0
[costs.control]
type = "control"
weight = 0.01
''')
    robot, _, problem, _, desc = build_problem(PlanConfig(problem=str(tmp_path / "cp.toml")))
    assert not robot.builtin and robot.underactuated and problem.n_u == 1
    assert desc["robot"]["unactuated"] == ["pole"] and desc["robot"]["gravity"] == 9.82
    assert problem.bounds.u_upper.tolist() == [10.0]
