"""The compiled task messages (raico/planning/task_messages.c through raico.planning.kernels.compile_task_set)
for every state-term kind of the cost-term examples, on a built-in arm and on a model-file robot:

- every example whose map has a compiled counterpart in the task-map table (raico.planning.term_kinds)
  compiles, and its gradient and Gauss-Newton Hessian equal the Python terms' (Drake's or the tree
  kernels' kinematics, the numpy logarithms) to rounding, relative to their scale;
- the compiled gradient equals central differences of the term's cost (the exact Jacobians);
- the logarithms' branches (the Taylor expansions near 0, the quaternion route near pi);
- a map without a compiled counterpart leaves the problem to Python.
"""

from __future__ import annotations

import ctypes
from dataclasses import replace

import numpy as np
import pytest

from raico.planning import kernels
from raico.planning.costs import COST_TERM_EXAMPLES, ControlCost, StateTarget, ViaPoint
from raico.planning.problem import Problem
from raico.planning.term_kinds import MAP_KINDS, kind_of_map
from raico.plants.dynamics_registry import make_dynamics
from raico.plants.robots import shared_robot
from raico.plants.taskmaps import FramePlacementError, FrameRotationError

pytestmark = pytest.mark.compiled   # reaches a C kernel: run under the sanitizers too

T = 4
STATE_EXAMPLES = sorted(n for n, ex in COST_TERM_EXAMPLES.items() if ex.kind == "state")
_ROBOTS: dict = {}


def _robot(name: str):
    """``arm5`` (built in) or ``ur5`` (example-robot-data's URDF, skipped where it is missing)."""
    if name not in _ROBOTS:
        if name == "ur5":
            from raico.plants.model_file import RobotSpec, example_robot_data, load_model

            erd = example_robot_data()
            if erd is None:
                pytest.skip("example-robot-data is not installed (it comes with the extra raico[baseline])")
            robot = load_model(RobotSpec(file=str(erd / "robots/ur_description/urdf/ur5_robot.urdf")))
            robot.spec = replace(robot.spec, end_effectors=(("tool", "tool0"),))  # the examples' frame
            _ROBOTS[name] = robot
        else:
            _ROBOTS[name] = shared_robot(name)
    return _ROBOTS[name]


def _problem(robot, terms) -> Problem:
    x0 = np.concatenate([robot.default_q, np.zeros(robot.n_q)])
    return Problem(make_dynamics("pseudo", robot, 0.01), x0, T, list(terms), [ControlCost(1e-2)])


def _evaluator(problem, compiled=None):
    compiled = compiled or kernels.compile_task_set(problem)
    assert compiled is not None
    fn, ctx, keep = compiled
    ev = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p, ctypes.c_void_p,
                          ctypes.c_void_p)(fn)

    def evaluate(x: np.ndarray, t: int) -> tuple[np.ndarray, np.ndarray]:
        n = x.size
        lx, lxx = np.empty(n), np.empty((n, n))
        ev(ctx, t, np.ascontiguousarray(x).ctypes.data, lx.ctypes.data, lxx.ctypes.data)
        keep.append(None)   # the context lives as long as this closure
        return lx, lxx
    return evaluate


def _states(robot, seed: int = 3) -> list[np.ndarray]:
    """States near the default posture and wide of it (1 rad), with velocities."""
    rng = np.random.default_rng(seed)
    n = robot.n_q
    return [np.concatenate([robot.default_q + s * rng.standard_normal(n), rng.standard_normal(n)])
            for s in (0.1, 0.3, 1.0)]


def _compiles(term) -> bool:
    if type(term) is StateTarget:
        return True
    row = kind_of_map(term.taskmap)
    return row is not None and row.compile is not None


@pytest.mark.numerics
@pytest.mark.parametrize("robot_name", ["arm5", "ur5"])
@pytest.mark.parametrize("example", STATE_EXAMPLES)
def test_compiled_messages_equal_the_terms_and_finite_differences(example, robot_name):
    ex = COST_TERM_EXAMPLES[example]
    robot = _robot(robot_name)
    if not ex.applies_to(robot_name):
        pytest.skip(f"{example} does not apply to {robot_name}")
    term = ex.build(robot, robot.default_q + 0.1)
    problem = _problem(robot, [term])
    if not _compiles(term):
        assert kernels.compile_task_set(problem) is None
        return
    evaluate = _evaluator(problem)
    active = problem.active_state_terms()
    some_cost = False
    for x in _states(robot):
        for t in range(T + 1):
            lx, lxx = evaluate(x, t)
            g, G = problem.point_state_derivatives(x, t, active[t])
            scale_g, scale_G = max(np.abs(g).max(), 1e-300), max(np.abs(G).max(), 1e-300)
            np.testing.assert_allclose(lx, g, rtol=0, atol=1e-9 * scale_g, err_msg=f"{example} t={t}")
            np.testing.assert_allclose(lxx, G, rtol=0, atol=1e-9 * scale_G, err_msg=f"{example} t={t}")
            if not active[t] or not np.any(g):
                assert not np.any(lx) and not np.any(lxx)
                continue
            some_cost = True
            # the gradient of the cost by central differences (h ~ eps^(1/3) of the state's scale)
            h = 1e-6 * max(1.0, np.abs(x).max())
            fd = np.array([(term.value((x + h * e)[None], np.array([t]))[0]
                            - term.value((x - h * e)[None], np.array([t]))[0]) / (2 * h) for e in np.eye(x.size)])
            np.testing.assert_allclose(lx, fd, rtol=0, atol=1e-5 * max(np.abs(fd).max(), 1e-300),
                                       err_msg=f"{example} t={t}: compiled gradient against differences")
    assert some_cost, f"{example}: no state where the term costs anything (the check would pass on zeros)"


def test_every_compiled_map_kind_has_an_example():
    """Each row of the task-map table with a compiled counterpart is exercised by a cost-term example."""
    robot = _robot("arm5")
    seen = set()
    for name in STATE_EXAMPLES:
        term = COST_TERM_EXAMPLES[name].build(robot, robot.default_q + 0.1)
        if hasattr(term, "taskmap"):
            seen.add(type(term.taskmap))
    assert {k.cls for k in MAP_KINDS if k.compile is not None} <= seen


def _rot(axis, angle: float) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


@pytest.mark.numerics
@pytest.mark.parametrize("angle", [0.0, 1e-7, 3e-5, 1.0, np.pi - 1e-4, np.pi - 1e-7])
def test_logarithm_branches(angle):
    """Orientation and placement errors where the target is ``angle`` away from the frame's pose: the
    Taylor branches near 0 (``theta < 6e-6``, ``< 1.2e-4``) and the quaternion route near pi."""
    robot = _robot("arm5")
    ee = next(iter(robot.end_effectors.values()))
    q0 = robot.default_q
    probe = FramePlacementError(robot, ee, np.eye(3), np.zeros(3))
    ctx = probe._set_plant(robot.P @ q0)
    X = probe.frame.CalcPoseInWorld(ctx)
    R0, p0 = X.rotation().matrix(), X.translation()
    Rt = R0 @ _rot([0.3, -1.0, 0.5], angle)
    maps = [FrameRotationError(robot, ee, Rt), FramePlacementError(robot, ee, Rt, p0 + [0.01, -0.02, 0.0])]
    terms = [ViaPoint(m, np.zeros(m.dim), [2], 10.0, precision=np.linspace(1, 2, m.dim), name=m.name) for m in maps]
    problem = _problem(robot, terms)
    evaluate = _evaluator(problem)
    x = np.concatenate([q0, np.zeros(robot.n_q)])
    lx, lxx = evaluate(x, 2)
    g, G = problem.point_state_derivatives(x, 2, problem.active_state_terms()[2])
    assert np.abs(g).max() > 0
    np.testing.assert_allclose(lx, g, rtol=0, atol=1e-9 * np.abs(g).max())
    np.testing.assert_allclose(lxx, G, rtol=0, atol=1e-9 * np.abs(G).max())


def test_cost_kinds_are_named_alike_in_python_and_c():
    import re
    from pathlib import Path

    src = (Path(kernels.__file__).with_name("task_messages.c")).read_text()
    body = re.search(r"enum cost_kind \{([^}]*)\}", src).group(1)
    c_enum = {k.strip().split("=")[0].strip()[3:]: int(k.split("=")[1]) for k in body.split(",")}
    assert c_enum == {k.name: int(k) for k in kernels.CostKind}


# -- the task-map table: every row complete ---------------------------------------------------------
def _descriptions(robot) -> dict:
    """A description of every map kind the objective writes (raico.planning.objective's writers)."""
    from raico.planning import objective as ob

    ee = next(iter(robot.end_effectors.values()))
    R, p = np.eye(3), np.array([0.3, 0.1, 0.4])
    return {"frame_points": ob.frame_points(ee, "ee", axes=(0, 2)), "roll": ob.roll(ee),
            "cog": ob.cog((0, 1)), "joints": ob.joints("joints", [0, 2]),
            "frame_rotation": ob.frame_rotation(ee, R, "rot"), "frame_placement": ob.frame_placement(ee, R, p, "pose"),
            "distances": _distances_description()}


def _distances_description() -> dict:
    """Signed distances of a pair of scene objects (the built-in arm carries no collision geometry)."""
    scene = [{"name": "ball", "type": "sphere", "pose": [0.5, 0.0, 0.3, 0.0, 0.0, 0.0], "radius": 0.05},
             {"name": "box", "type": "box", "pose": [0.5, 0.3, 0.3, 0.0, 0.0, 0.0], "size": [0.1, 0.1, 0.1]}]
    return {"map": "distances", "name": "gap", "scene": scene, "pairs": [["ball", "box"]], "max_distance": 1.0}


def test_every_row_builds_labels_and_names_a_crocoddyl_residual():
    """Each row: its description builds its class (raico.planning.objective.build_taskmap), its labels
    name every component, its crocoddyl residual function exists; and the table has a row for
    every description the objective writes."""
    from raico.pipeline.recordings.tasks import map_components
    from raico.planning.crocoddyl import costs as crocoddyl_costs
    from raico.planning.objective import build_taskmap

    robot = _robot("arm5")
    descs = _descriptions(robot)
    assert set(descs) == {k.key for k in MAP_KINDS}
    for row in MAP_KINDS:
        tm = build_taskmap(robot, descs[row.key])
        assert type(tm) is row.cls and kind_of_map(tm) is row
        names, per_point, unit, _ = map_components(descs[row.key], tm.dim, tm.name, list(robot.joint_names))
        assert len(names) == tm.dim and per_point >= 1 and unit
        assert row.crocoddyl is None or callable(getattr(crocoddyl_costs, row.crocoddyl, None)), row.key
    with pytest.raises(ValueError, match="unknown task map kind"):
        build_taskmap(robot, {"map": "nope", "name": "x"})


@pytest.mark.numerics
@pytest.mark.parametrize("robot_name", ["arm5", "ur5"])
def test_rows_equal_the_batched_terms(robot_name):
    """``kernels.task_rows`` (the sweeps' batched linearization and the iteration's cost) equals
    ``Problem.state_derivatives`` and the state terms' summed values along a trajectory."""
    robot = _robot(robot_name)
    q0 = robot.default_q + 0.1
    names = [n for n in STATE_EXAMPLES if COST_TERM_EXAMPLES[n].applies_to(robot_name)]
    terms = [COST_TERM_EXAMPLES[n].build(robot, q0) for n in names]
    terms = [t for t in terms if _compiles(t)]
    problem = _problem(robot, terms)
    compiled = kernels.compile_task_set(problem)
    X = np.stack(_states(robot) + _states(robot, seed=4)[:T + 1 - 3])
    steps = np.arange(T + 1)
    (lx, lxx), costs = kernels.task_rows(compiled, T, X, steps, costs=True)
    g, G = problem.state_derivatives(X, steps)
    ref = sum(t.value(X, steps) for t in problem.state_terms)
    assert np.abs(ref).max() > 0
    np.testing.assert_allclose(lx, g, rtol=0, atol=1e-9 * np.abs(g).max())
    np.testing.assert_allclose(lxx, G, rtol=0, atol=1e-9 * np.abs(G).max())
    np.testing.assert_allclose(costs, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())
    none, only = kernels.task_rows(compiled, T, X, steps, derivatives=False, costs=True)
    assert none is None and np.array_equal(only, costs)
    with pytest.raises(ValueError, match="steps must lie"):
        kernels.task_rows(compiled, T, X, steps + 1)


def test_every_cost_term_row_builds_and_names_a_crocoddyl_residual():
    """The cost-term table: each row's description (raico.planning.objective's writers) builds its class on
    its side of the objective, and its crocoddyl function exists."""
    from raico.planning import objective as ob
    from raico.planning.crocoddyl import costs as crocoddyl_costs
    from raico.planning.term_kinds import kind_of_term, term_kinds

    robot = _robot("arm5")
    n, ee = robot.n_q, next(iter(robot.end_effectors.values()))
    descs = {"via": ob.via("v", ob.frame_points(ee, "ee"), np.zeros(3), [2], 1.0),
             "inequality": ob.inequality("b", ob.joints("joints", [0]), [[1.0]], [0.5], [1, 2], 10.0),
             "state": ob.state("s", np.zeros(2 * n), [T], 1.0),
             "control": ob.control(1e-2), "control_limit": ob.control_limit(-np.ones(n), np.ones(n), 1e3),
             "collision": ob.collision("c", _distances_description(), 0.02, True, [1, 2], 10.0)}
    descs["control@gravity"] = {**ob.control(1e-2, name="toward_gravity"), "target": "gravity", "controls": "torque"}
    assert set(descs) == {k.key for k in term_kinds()}
    objective = ob.build_terms(robot, list(descs.values()), T)
    built = {kind_of_term(t).key: (t, side) for side, ts in (("state", objective.state_terms),
                                                             ("control", objective.control_terms),
                                                             ("joint", objective.joint_terms)) for t in ts}
    for row in term_kinds():
        term, side = built[row.key]
        assert type(term) is row.cls and side == row.side
        assert row.crocoddyl is None or callable(getattr(crocoddyl_costs, row.crocoddyl, None)), row.key
    with pytest.raises(ValueError, match="unknown cost term kind"):
        ob.build_term(robot, {"term": "nope", "name": "x"})


@pytest.mark.numerics
@pytest.mark.parametrize("robot_name", ["arm5", "nao", "ur5"])
def test_control_toward_gravity_compiled(robot_name):
    """The control toward gravity (a joint term: its state part at the controls set_task_controls
    gives) compiled: point messages, batched rows and costs equal the Python term's (Drake's gravity
    forces and their AutoDiffXd Jacobian), on an arm, on the Nao (planning coordinates mapped to the
    plant's by P, not the identity) and on a model-file robot; nothing at step T. The Python term's
    gravity is the compiled tree's too where it exists: it equals Drake's AutoDiffXd route."""
    from raico.planning.costs import ControlGravity

    robot = _robot(robot_name)
    term = ControlGravity(robot, 0.3, T, precision=np.linspace(1.0, 2.0, robot.n_q), name="toward_gravity")
    x0 = np.concatenate([robot.default_q, np.zeros(robot.n_q)])
    problem = Problem(make_dynamics("pseudo", robot, 0.01), x0, T, [], [ControlCost(1e-2)], [term])
    compiled = kernels.compile_task_set(problem)
    assert compiled is not None
    rng = np.random.default_rng(11)
    X = x0 + 0.3 * rng.standard_normal((T + 1, problem.n_x))
    U = 2.0 * rng.standard_normal((T, problem.n_u))
    problem.set_nominal(X, U)
    kernels.set_task_controls(compiled, U)
    evaluate = _evaluator(problem, compiled)
    for t in range(T + 1):
        lx, lxx = evaluate(X[t], t)
        g, G = problem.point_state_derivatives(X[t], t)
        if t == T:
            assert not np.any(lx) and not np.any(g)
            continue
        np.testing.assert_allclose(lx, g, rtol=0, atol=1e-9 * np.abs(g).max())
        np.testing.assert_allclose(lxx, G, rtol=0, atol=1e-9 * np.abs(G).max())
    (lx, lxx), costs = kernels.task_rows(compiled, T, X, np.arange(T + 1), costs=True)
    g, G = problem.state_derivatives(X)
    np.testing.assert_allclose(lx, g, rtol=0, atol=1e-9 * np.abs(g).max())
    np.testing.assert_allclose(lxx, G, rtol=0, atol=1e-9 * np.abs(G).max())
    ref = np.r_[term.joint_value(X[:-1], U), 0.0]
    np.testing.assert_allclose(costs, ref, rtol=1e-9, atol=1e-9 * ref.max())
    with pytest.raises(ValueError, match="U has shape"):
        kernels.set_task_controls(compiled, U[:-1])
    from raico.plants.dynamics import GravityTorques
    from raico.plants.fast_analytic import TreeGravityTorques

    assert type(term.gravity) is TreeGravityTorques
    drake = GravityTorques(robot)   # Drake's gravity forces and their AutoDiffXd Jacobian
    for x in X:
        g_tree, G_tree = term.gravity.value_and_jacobian(x[:robot.n_q])
        g_ad, G_ad = drake.value_and_jacobian(x[:robot.n_q])
        np.testing.assert_allclose(g_tree, g_ad, rtol=0, atol=1e-9 * np.abs(g_ad).max())
        np.testing.assert_allclose(G_tree, G_ad, rtol=0, atol=1e-9 * np.abs(G_ad).max())


@pytest.mark.numerics
def test_raico_with_the_gravity_term_compiled_equals_the_numpy_sweeps(monkeypatch):
    """R-AICO on the arm with a via-point and the control toward gravity: the compiled sweeps (task
    messages, batched rows, iteration costs in C) give the numpy sweeps' iterations to rounding."""
    from raico.planning.aico import AICOOptions, aico
    from raico.planning.aico.sweeps import Sweeps
    from raico.planning.costs import ControlGravity

    robot = _robot("arm5")
    ee = next(iter(robot.end_effectors.values()))
    Tn = 30

    def make():
        from raico.plants.taskmaps import FramePoints

        tm = FramePoints(robot, ee)
        x0 = np.concatenate([robot.default_q, np.zeros(robot.n_q)])
        via = ViaPoint(tm, tm.value(robot.default_q) + [0.05, 0.0, -0.05], [Tn], 1e4, name="reach")
        grav = ControlGravity(robot, 1e-2, Tn, name="toward_gravity")
        return Problem(make_dynamics("analytic", robot, 0.01), x0, Tn, [via], [], [grav])

    assert kernels.compile_task_set(make()) is not None
    out = {}
    for compiled in (True, False):
        monkeypatch.setattr(Sweeps, "compiled", compiled)
        out[compiled] = aico(make(), AICOOptions(alpha=1.0, iterations=4, tol_rel=0.0))
    a, b = out[True], out[False]
    assert a.iterations == b.iterations == 4 and str(a.status) == str(b.status)
    assert [h.repeats for h in a.history] == [h.repeats for h in b.history]
    np.testing.assert_allclose(a.costs, b.costs, rtol=1e-9)
    np.testing.assert_allclose(a.X, b.X, rtol=0, atol=1e-8 * np.abs(b.X).max())
