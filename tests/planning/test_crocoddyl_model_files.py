"""crocoddyl on robots from model files: Pinocchio's model equals Drake's, crocoddyl's cost equals
raico's, and crocoddyl's Kinova example is reproduced through the problem file.

The arms of example-robot-data (installed with crocoddyl, the extra ``raico[baseline]``): Drake and
Pinocchio read the same repaired URDF text; their mass matrices (armature included), bias terms
(gravity, Coriolis and joint damping) and frame placements must agree at random states, continuous
joints turned past pi. Skipped with the reason where crocoddyl or example-robot-data is missing.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from raico.planning import crocoddyl as cm
from tests.tolerance import assert_close, bound, close, cond_of

pytestmark = pytest.mark.skipif(not cm.AVAILABLE, reason=f"crocoddyl baseline: {cm.UNAVAILABLE_REASON}")

RTOL = 1e-9
KINOVA = "raico/problems/crocoddyl/kinova_reach.toml"
# name -> (file under example-robot-data's robots/, locked joints, armature by joint index or one number)
ARMS = {
    "kinova": ("kinova_description/robots/kinova.urdf", {}, 0.02),
    "panda": ("panda_description/urdf/panda.urdf", {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0}, 0.1),
    "ur5": ("ur_description/urdf/ur5_robot.urdf", {}, 0.0),
    "xarm7": ("xarm_description/urdf/xarm7.urdf", {}, 0.05),
    "z1": ("z1_description/urdf/z1.urdf", {}, 0.0),
    "talos_left_arm": ("talos_data/robots/talos_left_arm.urdf", {}, (0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.0)),
}


def _erd():
    from raico.plants.model_file import example_robot_data

    erd = example_robot_data()
    if erd is None:
        pytest.skip("example-robot-data is not installed (it comes with the extra raico[baseline])")
    return erd


def _spec(name: str):
    from raico.plants.model_file import RobotSpec

    file, locked, armature = ARMS[name]
    return RobotSpec(file=str(_erd() / "robots" / file), locked=tuple(sorted(locked.items())),
                     armature=armature if isinstance(armature, float) else ())


READINGS = [*ARMS, "kinova:angle"]  # Pinocchio's own cos/sin joints for each, and the Kinova's as angles too


@pytest.fixture(scope="module")
def arms():
    """name -> (Drake robot, Pinocchio model, StateMap), the armature set per joint where given;
    continuous joints as Pinocchio reads them (cos, sin), and as angles for "kinova:angle"."""
    from dataclasses import replace

    from raico.planning.crocoddyl import pinocchio_robot
    from raico.plants.model_file import load_model

    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, (_, _, armature) in ARMS.items():
            spec = _spec(name)
            robot = load_model(spec)
            if not isinstance(armature, float):  # by joint name: the map must put each on its joint
                spec = replace(spec, armature=tuple(zip(robot.joint_names, armature)))
                robot = load_model(spec)
            out[name] = (robot, *pinocchio_robot(robot, "cos-sin"))
        out["kinova:angle"] = (out["kinova"][0], *pinocchio_robot(out["kinova"][0], "angle"))
    return out


def _random_states(robot, smap, k: int, seed: int):
    """``k`` raico states: the default posture plus N(0, 1) rad, continuous joints past pi, N(0, 1) rad/s."""
    rng = np.random.default_rng(seed)
    n = robot.n_q
    Q = robot.default_q + rng.standard_normal((k, n))
    Q[:, smap.continuous] += 2.5 * np.sign(rng.standard_normal((k, int(smap.continuous.sum()))))
    return np.concatenate([Q, rng.standard_normal((k, n))], axis=1)


def _drake_M_h(robot, q, v):
    """Drake's mass matrix (rotor inertia included) and ``h = C v - tau_g + D v`` (force elements:
    gravity and joint damping), as raico's analytic dynamics compute them."""
    from pydrake.multibody.tree import MultibodyForces_

    plant = robot.plant
    ctx = robot.set_state(q, v, plant.CreateDefaultContext())
    forces = MultibodyForces_[float](plant)
    plant.CalcForceElementsContribution(ctx, forces)
    h = plant.CalcInverseDynamics(ctx, np.zeros(plant.num_velocities()), forces)
    return plant.CalcMassMatrix(ctx), h, ctx


def _rel(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / max(np.max(np.abs(b)), 1e-300))


@pytest.mark.numerics
@pytest.mark.parametrize("name", READINGS)
def test_drake_and_pinocchio_agree_on_mass_matrix_bias_and_frames(arms, name):
    import pinocchio as pin

    from raico.planning.crocoddyl import frame_id

    robot, model, smap = arms[name]
    assert sorted(model.names[1:]) == sorted(robot.joint_names)
    if name.startswith("kinova"):
        assert (smap.continuous.sum(), model.nq, model.nv) == ((3, 9, 6) if name == "kinova" else (0, 6, 6))
    arm = np.asarray(model.armature)[smap.v_index]
    assert np.any(arm > 0) == (name not in ("ur5", "z1"))
    plant = robot.plant
    frames = [plant.get_frame(i) for i in _frame_indices(plant)]
    frames = [f for f in frames if f.body().name() != "world" and f.name() != "world"]
    ids = {f.name(): frame_id(model, robot, f.name()) for f in frames}  # links and Drake's joint frames
    assert len(ids) > robot.n_q
    data = model.createData()
    for x in _random_states(robot, smap, 3, seed=7):
        q, v = x[:robot.n_q], x[robot.n_q:]
        xp = smap.x_to_pin(x)
        qp, vp = xp[:model.nq], xp[model.nq:]
        M_drake, h_drake, ctx = _drake_M_h(robot, q, v)
        M = pin.crba(model, data, qp)
        M = np.triu(M) + np.triu(M, 1).T  # crba fills the upper triangle
        M_pin = M[np.ix_(smap.v_index, smap.v_index)]
        h_pin = (pin.rnea(model, data, qp, vp, np.zeros(model.nv)) + np.asarray(model.damping) * vp)[smap.v_index]
        assert _rel(M_pin, M_drake) <= RTOL, name
        assert _rel(h_pin, h_drake) <= RTOL, name
        pin.framesForwardKinematics(model, data, qp)
        for f in frames:
            X = f.CalcPoseInWorld(ctx)
            oMf = data.oMf[ids[f.name()]]
            # metres of a robot of about 1 m, rotation entries of scale 1: equal up to rounding
            assert close(oMf.translation, X.translation(), scale=1.0), (name, f.name())
            assert close(oMf.rotation, X.rotation().matrix(), scale=1.0), (name, f.name())
        # the map's way back: raico's angles from cos, sin (continuous joints past pi included)
        assert close(smap.x_to_raico(xp[None], q)[0], x, scale=1.0)


def _frame_indices(plant):
    from pydrake.multibody.tree import FrameIndex

    return [FrameIndex(i) for i in range(plant.num_frames())]


# ----------------------------------------------------------------------------- costs
def raico_problem(path):
    """raico's problem of a problem file at its start posture (q0-std 0), with the analytic dynamics
    the plan stage ends up with for these arms (the compiled tree model)."""
    from raico.planning.objective import build_terms
    from raico.planning.problem import Problem
    from raico.plants.fast_analytic import TreeAnalyticDynamics
    from raico.stages.plan.stage import PlanConfig, robot_and_task

    cfg = PlanConfig(problem=str(path), solver="fddp", dynamics="analytic", q0_std=0.0).normalized()
    robot, task = robot_and_task(cfg)
    q0 = robot.default_q.copy()
    objective = build_terms(robot, task.build(robot, q0, task.T), task.T, "torque")
    x0 = np.concatenate([q0, np.zeros(robot.n_q)])
    return robot, Problem(TreeAnalyticDynamics(robot, task.dt), x0, task.T, objective.state_terms,
                          objective.control_terms, objective.joint_terms)


EVERY_TERM = """
name = "kinova-every-term"
[robot]
file = "package://example-robot-data/robots/kinova_description/robots/kinova.urdf"
start = "arm_up"
armature = 0.01
[horizon]
T = 40
dt = 0.01
[dynamics]
model = "analytic"
[costs.hand]
type = "frame_position"
frame = "j2s6s200_end_effector"
target = [0.5, 0.3]
axes = [0, 2]
times = "all"
weight = 3.0
precision = [1.0, 2.0]
[costs.fingers]
type = "frame_position"
frame = "j2s6s200_link_6"
points = [[0.0, 0.0, 0.1], [0.05, 0.0, 0.0]]
target = "start"
relative = "start"
times = [10, 20]
weight = 5.0
[costs.hand_down]
type = "frame_orientation"
frame = "j2s6s200_end_effector"
rpy = [3.14159, 0.0, 0.5]
times = "last"
weight = 7.0
precision = [1.0, 1.0, 0.5]
[costs.roll]
type = "frame_orientation"
frame = "j2s6s200_end_effector"
angle = "roll"
target = 0.4
times = [25]
weight = 2.0
[costs.pose]
type = "frame_placement"
frame = "j2s6s200_link_4"
position = [0.2, 0.1, 0.6]
rpy = [0.1, 0.2, 0.3]
times = [30, 40]
weight = 11.0
[costs.com]
type = "com"
target = [0.05, -0.02]
axes = [0, 1]
times = "all"
weight = 13.0
[costs.wrist]
type = "posture"
joints = ["j2s6s200_joint_4", "j2s6s200_joint_5"]
target = "start"
times = "all"
weight = 0.7
precision = [1.0, 3.0]
[costs.rest]
type = "state"
target = "start"
times = "all"
weight = 0.3
precision = [1, 1, 1, 1, 1, 1, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6]
[costs.effort]
type = "control"
weight = 0.05
target = [0.1, -0.2, 0.3, 0.0, 0.1, 0.0]
[costs.torque_limit]
type = "control_limit"
weight = 100.0
lower = [-1.0, -1.0, -1.0, -0.5, -0.5, -0.5]
upper = [1.0, 1.0, 1.0, 0.5, 0.5, 0.5]
[costs.limits]
type = "joint_limit"
times = "all"
weight = 50.0
[costs.base_turn]
type = "joint_limit"
joints = ["j2s6s200_joint_1", "j2s6s200_joint_6"]
lower = [1.2, -0.3]
upper = [1.6, 0.2]
times = "all"
weight = 20.0
"""


def _trajectory(problem, seed: int, spread: float = 0.3):
    """A random trajectory about the start (not a rollout: costs need none), torques N(0, 2)."""
    rng = np.random.default_rng(seed)
    T, n = problem.T, problem.n_u
    X = np.tile(problem.x0, (T + 1, 1))
    X[:, :n] += spread * rng.standard_normal((T + 1, n))
    X[:, n:] += rng.standard_normal((T + 1, n))
    return X, 2.0 * rng.standard_normal((T, n))


def _crocoddyl_term_costs(cp, X, U) -> dict[str, float]:
    """Each raico term's total as crocoddyl computes it (a term split over points summed)."""
    out: dict[str, float] = {}
    Xp, Up = cp.to_pin(X), cp.controls_to_pin(U)
    sp = cp.shooting
    for t in range(cp.T + 1):
        m = sp.runningModels[t] if t < cp.T else sp.terminalModel
        d = m.createData()
        m.calc(d, Xp[t], Up[t]) if t < cp.T else m.calc(d, Xp[t])
        scale = cp.dt if t < cp.T else 1.0
        weights = {k: c.weight for k, c in m.differential.costs.costs.todict().items()}
        for key, item in d.differential.costs.costs.todict().items():
            name = key.split("/")[0]
            out[name] = out.get(name, 0.0) + scale * weights[key] * item.cost
    return out


@pytest.fixture(scope="module")
def every_term_problem(tmp_path_factory):
    path = tmp_path_factory.mktemp("problems") / "every_term.toml"
    path.write_text(EVERY_TERM)
    return raico_problem(path)


@pytest.fixture(scope="module", params=["angle", "cos-sin"])
def every_term(request, every_term_problem):
    robot, problem = every_term_problem
    return robot, problem, cm.build(problem, request.param)


@pytest.fixture(scope="module")
def kinova_problem():
    return raico_problem(KINOVA)


@pytest.fixture(scope="module")
def kinova(kinova_problem):
    """The Kinova reach translated exactly (continuous joints as angles)."""
    robot, problem = kinova_problem
    return robot, problem, cm.build(problem)


@pytest.fixture(scope="module")
def kinova_cos_sin(kinova_problem):
    """The Kinova reach with Pinocchio's own continuous joints: crocoddyl's example."""
    robot, problem = kinova_problem
    return robot, problem, cm.build(problem, "cos-sin")


@pytest.mark.numerics
@pytest.mark.compiled
def test_every_term_of_a_problem_file_costs_the_same_in_crocoddyl(every_term):
    """Every term alike on both translations (the random trajectory keeps the continuous joints
    within pi of every reference, where crocoddyl's wrapped differences are raico's)."""
    from raico.planning.costs import TaskInequality, ViaPoint

    robot, problem, cp = every_term
    kinds = {type(t).__name__ + ("/" + type(t.taskmap).__name__ if isinstance(t, (ViaPoint, TaskInequality)) else "")
             for t in problem.state_terms + problem.control_terms}
    assert kinds >= {"ViaPoint/FramePoints", "ViaPoint/FrameRotationError", "ViaPoint/RollAngle",
                     "ViaPoint/FramePlacementError", "ViaPoint/CenterOfMass", "ViaPoint/JointPositions",
                     "StateTarget", "ControlCost", "ControlLimit", "TaskInequality/JointPositions"}
    assert cp.smap.continuous.sum() == (3 if cp.pmodel.nq == 9 else 0)  # the Kinova's cos/sin joints, or none
    for seed in range(3):
        X, U = _trajectory(problem, seed)
        raico_terms = problem.cost_terms(X, U)
        croc_terms = _crocoddyl_term_costs(cp, X, U)
        assert set(croc_terms) == set(raico_terms)
        for name, c in raico_terms.items():
            assert c > 0, name  # every term counts in the compared trajectory
            assert abs(croc_terms[name] - c) <= RTOL * c, (name, croc_terms[name], c)
        total = problem.cost(X, U)
        assert abs(cp.cost(X, U) - total) <= RTOL * total


@pytest.mark.numerics
@pytest.mark.compiled
def test_every_terms_gradient_and_gauss_newton_hessian_are_raicos(every_term):
    """At nodes where every state term is active (t = 20: the points, t = 25: the roll, t = 40 = T: the
    pose), crocoddyl's cost gradient and Gauss-Newton Hessian in its tangent coordinates are raico's
    ``l_x``, ``l_xx`` (and ``l_u``, ``l_uu`` on a running node), through the map's permutation."""
    robot, problem, cp = every_term
    X, U = _trajectory(problem, 4)
    idx = cp.smap.tangent_index
    for t in (20, 25, problem.T):
        m = cp.shooting.runningModels[t] if t < problem.T else cp.shooting.terminalModel
        d = m.createData()
        x = cp.smap.x_to_pin(X[t])
        if t < problem.T:
            u = cp.smap.u_to_pin(U[t])
            m.calc(d, x, u)
            m.calcDiff(d, x, u)
            lu, luu = problem.control_derivatives(U[t][None])
            Lu, Luu = np.asarray(d.Lu)[cp.smap.v_index], np.asarray(d.Luu)[np.ix_(cp.smap.v_index, cp.smap.v_index)]
            assert np.allclose(Lu, lu[0], rtol=RTOL, atol=RTOL * np.abs(lu).max())
            assert np.allclose(Luu, luu[0], rtol=RTOL, atol=RTOL * np.abs(luu).max())
        else:
            m.calc(d, x)
            m.calcDiff(d, x)
        lx, lxx = problem.point_state_derivatives(X[t], t)
        Lx, Lxx = np.asarray(d.Lx)[idx], np.asarray(d.Lxx)[np.ix_(idx, idx)]
        assert np.allclose(Lx, lx, rtol=RTOL, atol=RTOL * np.abs(lx).max()), t
        assert np.allclose(Lxx, lxx, rtol=RTOL, atol=RTOL * np.abs(lxx).max()), t


GRAVITY = """
name = "ur5-hold"
[robot]
file = "package://example-robot-data/robots/ur_description/urdf/ur5_robot.urdf"
start = { shoulder_lift_joint = -1.2, elbow_joint = 1.6 }
armature = 0.01
[horizon]
T = 10
dt = 0.01
[dynamics]
model = "analytic"
[costs.reach]
type = "frame_position"
frame = "tool0"
target = [0.1, 0.0, -0.1]
relative = "start"
times = "last"
weight = 1e3
[costs.hold]
type = "control"
target = "gravity"
weight = [0.01, 0.02, 0.03, 0.04, 0.05, 0.06]
[costs.effort]
type = "control"
target = [1.0, 2.0, 0.0, 0.0, 0.0, 0.5]
weight = [1e-3, 1e-3, 2e-3, 0.0, 1e-3, 1e-3]
"""


@pytest.mark.numerics
@pytest.mark.compiled
def test_control_toward_gravity_and_per_joint_weights_cost_and_derive_as_in_crocoddyl(tmp_path):
    """The control term toward the gravity-compensating torque is crocoddyl's ResidualModelControlGrav
    (r = u - g(q)) and per-joint control weights its weighted activation: the same cost per term, and at
    a running node crocoddyl's gradient and Gauss-Newton Hessian blocks are raico's (the state-control
    cross block, which raico's solvers take as zero, left out)."""
    _erd()
    path = tmp_path / "hold.toml"
    path.write_text(GRAVITY)
    robot, problem = raico_problem(path)
    assert [type(t).__name__ for t in problem.joint_terms] == ["ControlGravity"]
    cp = cm.build(problem)
    for seed in range(2):
        X, U = _trajectory(problem, seed)
        U = U + 20.0 * np.sign(U)   # torques about the size of the UR5's gravity torques (N m)
        raico_terms, croc_terms = problem.cost_terms(X, U), _crocoddyl_term_costs(cp, X, U)
        assert set(croc_terms) == set(raico_terms) == {"reach", "hold", "effort"}
        for name, c in raico_terms.items():
            assert c > 0 and abs(croc_terms[name] - c) <= RTOL * c, (name, croc_terms[name], c)
    problem.set_nominal(X, U)
    idx = cp.smap.tangent_index
    for t in (0, 5):
        m, x, u = cp.shooting.runningModels[t], cp.smap.x_to_pin(X[t]), cp.smap.u_to_pin(U[t])
        d = m.createData()
        m.calc(d, x, u)
        m.calcDiff(d, x, u)
        lu, luu = problem.control_derivatives(U)
        lx, lxx = problem.point_state_derivatives(X[t], t)
        v = cp.smap.v_index
        pairs = [(np.asarray(d.Lu)[v], lu[t]), (np.asarray(d.Luu)[np.ix_(v, v)], luu[t]),
                 (np.asarray(d.Lx)[idx], lx), (np.asarray(d.Lxx)[np.ix_(idx, idx)], lxx)]
        for croc, raico in pairs:
            assert np.abs(raico).max() > 0
            assert np.allclose(croc, raico, rtol=RTOL, atol=RTOL * np.abs(raico).max()), (t, croc, raico)


@pytest.mark.numerics
@pytest.mark.compiled
def test_kinova_problem_file_costs_the_same_in_crocoddyl(kinova, kinova_cos_sin):
    """Within pi of the references both translations cost what raico does; beyond (the base joint
    turned 4 rad) only the angle translation: crocoddyl's wrapped state difference costs less."""
    robot, problem, cp = kinova
    _, _, cs = kinova_cos_sin
    assert cp.pmodel.nq == 6 and cs.pmodel.nq == 9
    for seed in range(3):
        X, U = _trajectory(problem, seed)
        c = problem.cost(X, U)
        assert c > 0 and abs(cp.cost(X, U) - c) <= RTOL * c and abs(cs.cost(X, U) - c) <= RTOL * c
    X[:, 0] -= np.linspace(0.0, 4.0, problem.T + 1)
    c = problem.cost(X, U)
    assert abs(cp.cost(X, U) - c) <= RTOL * c
    assert c - cs.cost(X, U) > 0.05  # the state term's share on the base joint (weight 0.1 dt / 2)


@pytest.mark.numerics
def test_one_crocoddyl_step_is_one_raico_step(kinova_cos_sin, every_term):
    """At every node of a random trajectory, crocoddyl's next state (Pinocchio's ABA, semi-implicit
    Euler on cos/sin) is raico's (Drake's model): whole rollouts differ only by rounding that this
    open-loop unstable arm amplifies (about 1e-7 after 100 steps of random torques)."""
    import pinocchio as pin

    for _, problem, cp in (kinova_cos_sin, every_term):
        X, U = _trajectory(problem, 5)
        m = cp.shooting.runningModels[0]
        d, pdata = m.createData(), cp.pmodel.createData()
        for x, u in zip(X[:-1], U):
            m.calc(d, cp.smap.x_to_pin(x), cp.smap.u_to_pin(u))
            nxt = cp.smap.x_to_raico(np.asarray([cp.smap.x_to_pin(x), d.xnext]), x[:problem.n_u], cp.dt)[1]
            ref = problem.dynamics.step(x, u)
            # the accelerations solve M(q) a = tau - b: a factorization of order n_v, conditioned as M(q)
            M = pin.crba(cp.pmodel, pdata, cp.smap.x_to_pin(x)[:cp.pmodel.nq])
            rel = bound(cp.pmodel.nv, cond_of(np.triu(M) + np.triu(M, 1).T))
            assert np.max(np.abs(nxt - ref)) <= rel * max(1.0, np.max(np.abs(ref)))


@pytest.mark.numerics
def test_crocoddyls_kinova_example_is_reproduced_through_the_problem_file(kinova_cos_sin, kinova):
    """crocoddyl's examples/arm_manipulation_fwddyn.py logs: 72 iterations, cost 8.125, the hand at
    (0.60058, 0.19808, 0.49717): SolverFDDP.solve() with its defaults (cold start) on the translation
    with Pinocchio's own continuous joints. Its solution turns the base joint 3.65 rad and spins the
    wrist at 580 rad/s in the last step: raico's cost of it (the angles unwrapped along the steps) is
    the exact translation's, 8.179, not crocoddyl's wrapped 8.125."""
    import crocoddyl
    import pinocchio as pin

    robot, problem, cp = kinova_cos_sin
    solver = crocoddyl.SolverFDDP(cp.shooting)
    assert solver.solve()
    assert solver.iter == 72
    assert abs(solver.cost - 8.125) < 5e-4
    data = cp.pmodel.createData()
    pin.framesForwardKinematics(cp.pmodel, data, np.asarray(solver.xs[-1])[:cp.pmodel.nq])
    hand = data.oMf[cp.pmodel.getFrameId("j2s6s200_end_effector")].translation
    assert np.allclose(hand, [0.60058, 0.19808, 0.49717], atol=1e-5)
    X, U = cp.from_pin(solver.xs), cp.controls_from_pin(solver.us)
    assert X[-1, 11] > 500 and X[-1, 0] - X[0, 0] < -3.6  # the wrist's spin, the base's turn
    assert np.max(np.abs(problem.dynamics.step(X[-2], U[-1]) - X[-1])) < 1e-9  # unwrapped through the spin
    raico_cost = problem.cost(X, U)
    assert math.isclose(raico_cost, kinova[2].cost(X, U), rel_tol=1e-9)
    assert 8.17 < raico_cost < 8.19


def test_the_bench_row_of_crocoddyls_example_is_plain_fddp(crocoddyl_baseline):
    """The benchmark page's row "crocoddyl's example" runs the example's solver, FDDP, on the problem as the
    bench builds it (the problem file's default hard bounds, which ``box="auto"`` would turn into BoxFDDP):
    the logged 72 iterations (0-based) and cost 8.125."""
    from bench.crocoddyl_problems import PROBLEMS, kinova_example, plan_config
    from raico.stages.plan.stage import build_problem

    problem = build_problem(plan_config(PROBLEMS["kinova"]["file"], solver="fddp"))[2]
    assert problem.bounds is not None
    r, cost = kinova_example(problem)
    assert r.iterations == 73 and abs(cost - 8.125) < 5e-4


@pytest.mark.numerics
def test_fddp_solver_on_the_exact_translation_reports_raicos_cost(kinova):
    """The solver ``fddp`` of raico plan (x0 held at every node) and crocoddyl's cold start on the
    exact translation: the gains mapped from crocoddyl's tangent space, the controller rolled out on
    raico's model reaching crocoddyl's cost, which is raico's cost of it."""
    from raico.planning.crocoddyl import FDDPOptions, fddp
    from raico.planning.solvers import solve

    robot, problem, cp = kinova
    for r in (solve(problem, "fddp", {"iterations": 200}),
              fddp(problem, FDDPOptions(iterations=200, start="zero"), croc=cp)):
        assert str(r.status) == "converged" and 20 < r.iterations < 200
        assert r.O.shape == (problem.T, 6, 12)
        assert math.isclose(problem.cost(r.X, r.U), r.cost, rel_tol=1e-6)
        assert r.cost < 8.125


def test_what_pinocchio_cannot_hold_is_refused_in_one_line():
    from raico.planning.costs import TaskInequality
    from raico.planning.crocoddyl import pinocchio_robot
    from raico.plants.model_file import RobotSpec, load_model
    from raico.plants.taskmaps import CenterOfMass

    spec = RobotSpec(file=str(_erd() / "robots" / ARMS["talos_left_arm"][0]), weld="gripper_left_base_link")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        robot = load_model(spec)
    with pytest.raises(cm.NotExpressible, match=r"welded on 'gripper_left_base_link'.*rooted at 'arm_left_1_link'"):
        pinocchio_robot(robot)
    robot, problem = raico_problem(KINOVA)
    support = TaskInequality(CenterOfMass(robot, axes=(0, 1)), np.eye(2), np.zeros(2), [3], 1.0, name="support")
    with pytest.raises(cm.NotExpressible, match="support.*not on joint positions"):
        cm.build(type(problem)(problem.dynamics, problem.x0, problem.T, [*problem.state_terms, support],
                               problem.control_terms, []))


# ----------------------------------------------------------------------------- the Talos arm
TALOS = "raico/problems/crocoddyl/talos_arm_reach.toml"
# crocoddyl 1.0.0's examples/log/arm_manipulation.log: per DDP iteration its cost and its stopping
# value (then the sum of ||Q_u||^2 over the nodes), stopped below th_stop = 1e-9 at iteration 6
TALOS_LOG = [(0.428053, 1.91916e-08), (0.375971, 4.33645e-08), (0.275989, 3.04933e-08), (0.246724, 1.14202e-08),
             (0.197477, 1.20824e-08), (0.192250, 1.00371e-09), (0.189677, 2.26074e-10)]


@pytest.fixture(scope="module")
def talos():
    return raico_problem(TALOS)


@pytest.mark.numerics
@pytest.mark.compiled
def test_talos_problem_file_costs_the_same_in_crocoddyl_and_targets_the_examples_frame(talos):
    import pinocchio as pin

    robot, problem = talos
    cp = cm.build(problem)
    assert robot.n_q == 7 and np.allclose(np.asarray(cp.pmodel.armature), [0.1] * 6 + [0.0])
    assert np.any(np.asarray(cp.pmodel.damping) > 0)  # Drake's damping, through the damped actuation
    for seed in range(2):
        X, U = _trajectory(problem, seed)
        c = problem.cost(X, U)
        assert c > 0 and abs(cp.cost(X, U) - c) <= RTOL * c
    # the example's Pinocchio frame "gripper_left_joint" is the problem file's link frame
    data = cp.pmodel.createData()
    X, _ = _trajectory(problem, 3)
    pin.framesForwardKinematics(cp.pmodel, data, cp.smap.x_to_pin(X[7])[:cp.pmodel.nq])
    a = data.oMf[cp.pmodel.getFrameId("gripper_left_joint")]
    b = data.oMf[cp.pmodel.getFrameId("gripper_left_motor_double_link", pin.BODY)]
    assert close(a.homogeneous, b.homogeneous, scale=1.0)


@pytest.mark.numerics
def test_crocoddyls_talos_arm_example_is_reproduced_through_the_problem_file(talos):
    """crocoddyl 1.0.0's arm_manipulation.py (DDP, cold start, no joint damping: Pinocchio's ABA) logged
    7 iterations down to 0.1897. crocoddyl 3.2.0's DDP on the problem file's translation without the
    damping takes the same iterates (costs and crocoddyl 1.0's stopping value sum ||Q_u||^2 alike to
    0.2 %) and with 1.0's stopping rule stops where the log does; 3.2.0's own rule, the expected
    improvement |d1 + d2 / 2|, goes on (to 0.1429)."""
    import crocoddyl

    robot, problem = talos
    cp = cm.build(problem, damping=False)

    class Log(crocoddyl.CallbackAbstract):
        def __init__(self):
            crocoddyl.CallbackAbstract.__init__(self)
            self.rows = []

        def __call__(self, solver, *args):
            self.rows.append((solver.cost, sum(float(np.dot(q, q)) for q in solver.Qu), solver.isFeasible))

    solver = crocoddyl.SolverDDP(cp.shooting)
    log = Log()
    solver.setCallbacks([log])
    assert solver.solve()
    stop_10 = next(i for i, (_, stop, feasible) in enumerate(log.rows) if feasible and stop < 1e-9)
    assert stop_10 == 6
    for (cost, stop, _), (cost_log, stop_log) in zip(log.rows, TALOS_LOG):
        assert math.isclose(cost, cost_log, rel_tol=2e-3) and math.isclose(stop, stop_log, rel_tol=5e-3)
    assert len(log.rows) > 20 and solver.cost < 0.15  # 3.2.0's rule: further


# ----------------------------------------------------------------------------- MJCF and SDF
@pytest.mark.numerics
@pytest.mark.parametrize("path", ["raico/problems/suite/arm3_mjcf_reach.toml", "raico/problems/suite/arm3_sdf_reach.toml"])
def test_mjcf_and_sdf_robots_are_the_same_model_in_pinocchio_and_fddp_reports_raicos_cost(path):
    """Pinocchio's own MJCF reader, and the model built from Drake's reading of an SDF file, give Drake's
    mass matrix, bias (gravity, Coriolis, the file's joint damping) and frames; FDDP on the file's problem
    reaches a controller whose rollout on raico's model costs what crocoddyl says."""
    import pinocchio as pin

    from raico.planning.crocoddyl import frame_id, pinocchio_robot
    from raico.planning.solvers import solve

    robot, problem = raico_problem(path)
    model, smap = pinocchio_robot(robot)
    assert np.all(np.asarray(model.damping) > 0)          # the file's damping, read by both
    ids = {name: frame_id(model, robot, name) for name in ("tip", "fore", "upper")}   # may add frames
    data = model.createData()
    for x in _random_states(robot, smap, 3, seed=3):
        q, v = x[:robot.n_q], x[robot.n_q:]
        xp = smap.x_to_pin(x)
        M_drake, h_drake, ctx = _drake_M_h(robot, q, v)
        M = pin.crba(model, data, xp[:model.nq])
        M = (np.triu(M) + np.triu(M, 1).T)[np.ix_(smap.v_index, smap.v_index)]
        h = (pin.rnea(model, data, xp[:model.nq], xp[model.nq:], np.zeros(model.nv))
             + np.asarray(model.damping) * xp[model.nq:])[smap.v_index]
        assert _rel(M, M_drake) <= RTOL and _rel(h, h_drake) <= RTOL
        pin.framesForwardKinematics(model, data, xp[:model.nq])
        for name, fid in ids.items():
            X = robot.plant.GetFrameByName(name).CalcPoseInWorld(ctx)
            oMf = data.oMf[fid]
            assert_close(oMf.translation, X.translation(), scale=1.0, err_msg=name)  # metres
            assert_close(oMf.rotation, X.rotation().matrix(), scale=1.0, err_msg=name)
    r = solve(problem, "fddp", {"iterations": 60})
    assert math.isclose(problem.cost(r.X, r.U), r.cost, rel_tol=1e-6)
    assert r.cost < 1e-3 * r.initial_cost


def test_a_drake_joint_pinocchio_cannot_hold_is_refused_in_one_line():
    """A floating joint inside the tree (Drake's quaternion floating joint of a free root) is refused
    by the model built from Drake's plant."""
    from pydrake.multibody.plant import MultibodyPlant
    from pydrake.multibody.tree import SpatialInertia

    from raico.planning.crocoddyl import model_from_drake

    plant = MultibodyPlant(0.0)
    plant.AddRigidBody("floating", SpatialInertia.SolidSphereWithMass(1.0, 0.1))
    plant.Finalize()
    with pytest.raises(cm.NotExpressible, match=r"joint '.*' of free is a quaternion_floating joint in Drake"):
        model_from_drake(type("R", (), {"plant": plant, "name": "free"})())
