"""Plants, dynamics and task maps against facts and Drake; the dynamics
registry and the import graph of ``plants``. Derivatives against finite differences:
``tests/plants/test_derivatives.py`` (every registered model and task map)."""

import ast
from pathlib import Path

import numpy as np
import pytest

from raico.plants.dynamics import AnalyticDynamics, PseudoDynamics
from raico.plants.dynamics_registry import DYNAMICS, DynamicsSpec, dynamics_names, make_dynamics, register_dynamics
from raico.plants.fast_analytic import FastAnalyticDynamics
from raico.plants.robots import PLANTS, load_robot, shared_robot
from raico.plants.taskmaps import EndEffectorPosition, RollAngle

pytestmark = pytest.mark.compiled   # reaches a C kernel: run under the sanitizers too


def random_state(robot, seed=0):
    rng = np.random.default_rng(seed)
    q = robot.default_q + 0.1 * rng.standard_normal(robot.n_q)
    return q, 0.5 * rng.standard_normal(robot.n_q), rng.standard_normal(robot.n_q)


PLANNING_VIEWS = {  # n_q, plant positions, end effectors
    "pendulum": (1, 1, {"ee"}),
    "cartpole": (2, 2, {"tip"}),
    "arm5": (5, 5, {"ee"}),
    "biorob": (5, 5, {"ee"}),
    "nao": (25, 26, {"r_hand", "l_hand", "r_sole", "l_sole", "head"}),
}


@pytest.mark.numerics
@pytest.mark.parametrize("name", PLANTS)
def test_robot_has_planning_view(name):
    r = shared_robot(name)
    assert (r.n_q, r.plant.num_positions(), set(r.end_effectors)) == PLANNING_VIEWS[name]
    assert r.P.shape == (r.plant.num_positions(), r.n_q)
    # every plant joint follows exactly one planning coordinate
    assert set(np.unique(r.P)) <= {0.0, 1.0} and np.all(r.P.sum(1) == 1)
    q = np.random.default_rng(0).standard_normal(r.n_q)
    np.testing.assert_array_equal(r.to_plant_q(q), r.P @ q)
    assert len(set(r.joint_names)) == r.n_q and np.all(r.lower < r.upper)
    assert r.effort.shape == (r.n_q,) and np.all(r.effort[r.actuated] > 0)
    assert np.all(r.effort[np.setdiff1d(np.arange(r.n_q), r.actuated)] == 0)   # no motor (the cart-pole's pole)
    for frame in r.end_effectors.values():
        r.plant.GetFrameByName(frame)


@pytest.mark.numerics
def test_nao_facts():
    r = shared_robot("nao")
    assert r.n_q == 25 and r.plant.num_positions() == 26
    ctx = r.set_state(r.default_q)
    assert abs(r.plant.CalcTotalMass(ctx) - 5.31) <= 0.01
    # coupled hip: RHipYawPitch copies LHipYawPitch
    q = np.zeros(25)
    q[r.joint_names.index("LHipYawPitch")] = 0.3
    qp = r.to_plant_q(q)
    for jn in ("LHipYawPitch", "RHipYawPitch"):
        assert qp[r.plant.GetJointByName(jn).position_start()] == pytest.approx(0.3)
    # default posture: CoG over the left sole's support polygon; left sole at the world origin
    X_sole = r.plant.GetFrameByName("l_sole").CalcPoseInWorld(ctx)
    assert np.allclose(X_sole.translation(), 0) and np.allclose(X_sole.rotation().matrix(), np.eye(3))
    c = r.plant.CalcCenterOfMassPositionInWorld(ctx)
    lo, hi = r.support_polygon.min(0), r.support_polygon.max(0)
    assert np.all(c[:2] > lo) and np.all(c[:2] < hi) and c[2] > 0.2


@pytest.mark.numerics
def test_pendulum_facts():
    r = shared_robot("pendulum")
    dyn = AnalyticDynamics(r, 0.002)
    # m l^2 qdd = u - mu qd - m g l sin q, q = 0 hanging down
    q, v, u = np.array([0.7]), np.array([0.4]), np.array([1.5])
    expected = u - 1.0 * v - 9.81 * np.sin(q)
    # the bob carries a 1e-6 kg m^2 inertia about its centre (Drake needs one): rel. 1e-6
    assert dyn.qddot(q, v, u) == pytest.approx(expected, rel=1e-5)
    assert r.effort[0] == 10.0


@pytest.mark.numerics
@pytest.mark.parametrize("name", ["pendulum", "arm5", "biorob"])  # Nao: coupled, see the next test
def test_analytic_qddot_matches_drake_time_derivatives(name):
    r = shared_robot(name)
    dyn = AnalyticDynamics(r, 0.002)
    q, v, u = random_state(r, 1)
    ctx = r.plant.CreateDefaultContext()
    r.plant.SetPositions(ctx, q)
    r.plant.SetVelocities(ctx, v)
    r.plant.get_actuation_input_port().FixValue(ctx, r.actuation(u))
    xdot = r.plant.EvalTimeDerivatives(ctx).CopyToVector()
    assert np.allclose(xdot[r.n_q:], dyn.qddot(q, v, u), atol=1e-9)


@pytest.mark.numerics
def test_nao_reduced_model_keeps_the_coupling_in_drake():
    """Torques from the reduced model's inverse dynamics, applied to the 26-joint Drake plant,
    give accelerations P @ a: both hip yaw-pitch joints move together."""
    r = shared_robot("nao")
    dyn = AnalyticDynamics(r, 0.01)
    q, v, a = random_state(r, 5)
    ctx = r.plant.CreateDefaultContext()
    r.plant.SetPositions(ctx, r.to_plant_q(q))
    r.plant.SetVelocities(ctx, r.to_plant_q(v))
    from pydrake.multibody.tree import MultibodyForces_

    f = MultibodyForces_[float](r.plant)
    r.plant.CalcForceElementsContribution(ctx, f)
    tau26 = r.plant.CalcInverseDynamics(ctx, r.to_plant_q(a), f)
    assert np.allclose(r.P.T @ tau26, dyn.inverse_dynamics(q, v, a), atol=1e-9)
    r.plant.get_actuation_input_port().FixValue(ctx, r.actuation(tau26))
    acc = r.plant.EvalTimeDerivatives(ctx).CopyToVector()[r.plant.num_positions():]
    assert np.allclose(acc, r.to_plant_q(a), atol=1e-8)
    assert np.allclose(dyn.qddot(q, v, dyn.inverse_dynamics(q, v, a)), a, atol=1e-8)


@pytest.mark.numerics
def test_pseudo_dynamics_matrices():
    d = PseudoDynamics(2, 0.1)
    A, a, B = d.linearize(np.zeros(4), np.zeros(2))
    assert np.allclose(A, [[1, 0, .1, 0], [0, 1, 0, .1], [0, 0, 1, 0], [0, 0, 0, 1]])
    assert np.allclose(B, [[.01, 0], [0, .01], [.1, 0], [0, .1]]) and not a.any()


@pytest.mark.numerics
def test_frictionless_unactuated_pendulum_keeps_energy_in_drake_simulation():
    from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator

    r = load_robot("pendulum")
    r.plant.get_joint(r.plant.GetJointByName("theta").index())  # exists
    diagram = r.builder.Build()
    sim = Simulator(diagram)
    ResetIntegratorFromFlags(sim, "runge_kutta5", 1e-3).set_fixed_step_mode(True)
    ctx = r.plant.GetMyMutableContextFromRoot(sim.get_mutable_context())
    r.plant.GetJointByName("theta").SetDamping(ctx, 0.0)
    r.plant.get_actuation_input_port().FixValue(ctx, [0.0])
    r.plant.SetPositions(ctx, [2.0])
    r.plant.SetVelocities(ctx, [0.0])

    def energy():
        return r.plant.CalcKineticEnergy(ctx) + r.plant.CalcPotentialEnergy(ctx)

    e0 = energy()
    sim.AdvanceTo(5.0)
    assert abs(r.plant.GetPositions(ctx)[0] - 2.0) > 1e-3  # it moved
    assert abs(energy() - e0) < 1e-6 * max(1.0, abs(e0))


@pytest.mark.numerics
def test_roll_couples_with_the_reach():
    """arm5's roll is no single joint's angle. With a roll axis between two pitch axes (forearm roll,
    then wrist pitch) the hand's roll about its own axis moves with the shoulder, elbow, forearm roll and wrist,
    and turning the forearm moves the end effector too; the zero posture is the thesis's initial pose x2."""
    r = shared_robot("arm5")
    roll, ee = RollAngle(r, "ee"), EndEffectorPosition(r, "ee")
    assert np.allclose(r.default_q, 0) and np.allclose(ee.value(r.default_q), [1.0, 0.0, 0.0], atol=1e-8)
    assert roll.value(r.default_q)[0] == pytest.approx(0.0, abs=1e-9)
    q = np.array([0.3, -0.7, 1.1, -0.2, 0.4])
    V, J = roll.values_and_jacobians(q[None])
    assert all(abs(V[0, 0] - q[i]) > 0.05 for i in range(5))  # not any joint's angle
    assert np.sum(np.abs(J[0, 0]) > 1e-3) >= 4  # moved by four of the five joints
    turned = np.zeros(5)
    turned[r.joint_names.index("forearm_roll")] = 0.5
    assert np.linalg.norm(ee.value(turned) - ee.value(r.default_q)) > 0.01  # the roll is not free of the reach


def test_non_finite_inputs_give_nan_not_an_abort():
    r = shared_robot("arm5")
    dyn = AnalyticDynamics(r, 0.002)
    x = np.r_[r.default_q, np.zeros(5)]
    assert np.all(np.isnan(dyn.step(x, np.full(5, np.nan))))
    assert np.all(np.isnan(dyn.linearize(np.full(10, np.inf), np.zeros(5))[0]))
    V, J = EndEffectorPosition(r, "ee").values_and_jacobians(np.stack([r.default_q, np.full(5, np.nan)]))
    assert np.all(np.isfinite(V[0])) and np.all(np.isnan(V[1])) and np.all(np.isnan(J[1]))


def test_registry_builds_the_registered_models():
    assert {"pseudo", "analytic"} <= set(dynamics_names()) and list(DYNAMICS) == dynamics_names()
    assert all(isinstance(s, DynamicsSpec) and s.name == k and s.description for k, s in DYNAMICS.items())
    arm, nao = shared_robot("arm5"), shared_robot("nao")
    pseudo = make_dynamics("pseudo", arm, 0.01)
    assert isinstance(pseudo, PseudoDynamics) and pseudo.n_x == 10 and pseudo.dt == 0.01
    assert isinstance(make_dynamics("analytic", arm, 0.01), FastAnalyticDynamics)
    nao_model = type(make_dynamics("analytic", nao, 0.01))  # too big for symbolic code: tree kernels (C) or AutoDiffXd
    assert nao_model.__name__ in ("TreeAnalyticDynamics", "AnalyticDynamics") and nao_model is not FastAnalyticDynamics


def test_registry_refuses_bad_input(monkeypatch):
    arm = shared_robot("arm5")
    with pytest.raises(ValueError, match="^unknown dynamics 'rigid': choose one of pseudo, analytic"):
        make_dynamics("rigid", arm, 0.01)
    with pytest.raises(ValueError, match="^dynamics 'pseudo' takes no params$"):
        make_dynamics("pseudo", arm, 0.01, params={"w": np.ones(2)})
    with pytest.raises(ValueError, match="^dynamics name 'pseudo' is empty or already registered$"):
        register_dynamics("pseudo", lambda r, dt, p: PseudoDynamics(r.n_q, dt), "again")
    monkeypatch.setattr("raico.plants.dynamics_registry.DYNAMICS", dict(DYNAMICS))
    seen = []

    def build(r, dt, p):
        return seen.append(p) or PseudoDynamics(r.n_q, dt)

    with pytest.raises(ValueError, match="^dynamics 'fitted' needs params: register example_params too$"):
        register_dynamics("fitted", build, "test", needs_params=True)
    assert "fitted" not in dynamics_names()
    spec = register_dynamics("fitted", build, "test", needs_params=True,
                             example_params=lambda r: {"w": np.ones(2)})
    import raico.plants.dynamics_registry

    assert spec is raico.plants.dynamics_registry.DYNAMICS["fitted"] and dynamics_names()[-1] == "fitted"
    assert "fitted" not in DYNAMICS  # the test's copy of the registry, not the real one
    with pytest.raises(ValueError, match=r"^dynamics 'fitted' needs params \(fitted model parameters\)$"):
        make_dynamics("fitted", arm, 0.01)
    assert seen == []  # refused before the builder ran
    assert isinstance(make_dynamics("fitted", arm, 0.01, spec.example_params(arm)), PseudoDynamics)
    assert len(seen) == 1 and list(seen[0]) == ["w"] and np.array_equal(seen[0]["w"], np.ones(2))


def _plants_imports() -> dict[str, set[str]]:
    """``plants`` module -> the modules it imports (anywhere in the file, lazy imports too)."""
    root = Path(__file__).resolve().parents[2]
    graph = {}
    for path in sorted((root / "raico" / "plants").rglob("*.py")):
        name = ".".join(path.relative_to(root).with_suffix("").parts).removesuffix(".__init__")
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                deps.add(node.module)
            elif isinstance(node, ast.Import):
                deps |= {a.name for a in node.names}
        graph[name] = deps
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle of ``graph`` (module -> imported modules) as a path, or ``None``."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(m: str, path: list[str]) -> list[str] | None:
        if state.get(m) == 1:
            return path + [m]
        if state.get(m) == 2:
            return None
        state[m] = 1
        for d in sorted(graph.get(m, ())):
            found = visit(d, path + [m])
            if found:
                return found
        state[m] = 2
        return None

    return next((c for c in (visit(m, []) for m in sorted(graph)) if c), None)


def test_plants_has_no_import_cycle():
    everything = _plants_imports()
    assert not any(d.split(".")[0] in ("stages", "pipeline") for deps in everything.values() for d in deps)
    graph = {m: {d for d in deps if d.startswith("plants.")} for m, deps in everything.items()}
    assert not any(d in ("raico.plants.dynamics_registry", "raico.plants.fast_analytic") or d.startswith("raico.plants.codegen")
                   for d in graph["raico.plants.dynamics"])
    assert _cycle(graph) is None, " -> ".join(_cycle(graph))
    assert _cycle({"plants.a": {"plants.b"}, "plants.b": {"plants.a"}}) == ["plants.a", "plants.b", "plants.a"]


@pytest.mark.numerics
def test_biorob_actuator_facts_reach_drake():
    """The BioRob-like arm's reflected motor inertia reaches Drake and no joint damping does. At
    q = 0 (the arm stretched along +x) the wrist roll's axis is the hand's own axis, its centre of mass
    lies on it and its inertia is diagonal, so 1 N m there accelerates the roll alone, by hand:
    1 / (0.5 m r^2 + reflected inertia), rad/s^2, at any roll velocity (no damping)."""
    r = shared_robot("biorob")
    dyn = AnalyticDynamics(r, 0.002)
    j = r.joint_names.index("wrist_roll")
    u = np.zeros(r.n_q)
    u[j] = 1.0
    m, radius = 0.15, 0.02  # scripts/make_models.py: the hand
    by_hand = 1.0 / (0.5 * m * radius**2 + r.spec.armature)
    q, v = np.zeros(r.n_q), np.zeros(r.n_q)
    g = dyn.qddot(q, v, np.zeros(r.n_q))  # gravity alone (the roll feels none)
    acc = dyn.qddot(q, v, u) - g
    assert acc[j] == pytest.approx(by_hand, rel=1e-9) and abs(g[j]) < 1e-9
    assert np.allclose(np.delete(acc, j), 0.0, atol=1e-9)
    v[j] = 3.0  # a spinning roll: no damping torque, no change in its acceleration
    assert dyn.qddot(q, v, u)[j] == pytest.approx(acc[j] + g[j], rel=1e-9)
    assert [r.plant.GetJointByName(n).default_damping() for n in r.joint_names] == [0.0] * r.n_q


@pytest.mark.numerics
def test_pseudo_dynamics_schemes_of_appendix_c():
    """Euler (C.1), backward Euler (C.2, the default) and Heun (C.3) differ only in B's position block:
    0, dt^2 and dt^2/2; Heun's step is the exact motion under an acceleration held over the step."""
    from raico.plants.dynamics import PSEUDO_SCHEMES

    dt = 0.1
    for scheme, top in (("euler", 0.0), ("backward-euler", dt * dt), ("heun", dt * dt / 2)):
        A, a, B = PseudoDynamics(2, dt, scheme).linearize(np.zeros(4), np.zeros(2))
        assert np.allclose(A, [[1, 0, .1, 0], [0, 1, 0, .1], [0, 0, 1, 0], [0, 0, 0, 1]]) and not a.any()
        assert np.array_equal(B, np.vstack([top * np.eye(2), dt * np.eye(2)])), scheme
    assert set(PSEUDO_SCHEMES) == {"euler", "backward-euler", "heun"}
    # the default is bit for bit the former backward Euler
    assert np.array_equal(PseudoDynamics(5, 0.002).B, np.vstack([0.002 * 0.002 * np.eye(5), 0.002 * np.eye(5)]))
    x, u = np.array([0.3, -0.2, 1.0, 0.5]), np.array([2.0, -3.0])
    exact = np.r_[x[:2] + dt * x[2:] + dt * dt / 2 * u, x[2:] + dt * u]  # q(t + dt) under qddot = u held
    assert np.allclose(PseudoDynamics(2, dt, "heun").step(x, u), exact)
    arm = shared_robot("arm5")
    for name, scheme in (("pseudo", "backward-euler"), ("pseudo-euler", "euler"), ("pseudo-heun", "heun")):
        d = make_dynamics(name, arm, 0.01)
        assert isinstance(d, PseudoDynamics) and d.scheme == scheme
    with pytest.raises(ValueError, match="^unknown pseudo-dynamics scheme 'rk4'"):
        PseudoDynamics(2, dt, "rk4")
