"""crocoddyl's FDDP and BoxFDDP with a control term toward gravity on a model file whose joints are damped
(tests/data/lift6.urdf: a prismatic lift and five revolute joints, every one with ``<dynamics damping>``).

raico's term is ``w (u - g(q))^T C (u - g(q))`` on the control; crocoddyl's own control-gravity residual
measures its actuation's torque, ``u - D v`` under the damped actuation, so the adapter uses a residual on the
control there: the same cost per term, the same gradient and Gauss-Newton Hessian at a running node."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from raico.planning import crocoddyl as cm
from tests.tolerance import REL

pytestmark = pytest.mark.skipif(not cm.AVAILABLE, reason=f"crocoddyl baseline: {cm.UNAVAILABLE_REASON}")

DATA = Path(__file__).resolve().parents[1] / "data"
# the costs are sums over 21 nodes of Pinocchio's and Drake's recursions on a 6-joint tree, each rounding at a few
# eps of the largest term: the project's relative tolerance (tests/tolerance.py) bounds that with a wide margin
RTOL = REL


def hold_problem(tmp_path: Path, box: bool) -> Path:
    """The lift arm's reach with a control term toward gravity (and, ``box``, control limits: BoxFDDP)."""
    text = (DATA / "lift6_reach.toml").read_text().replace('file = "lift6.urdf"', f'file = "{DATA / "lift6.urdf"}"')
    text = text.replace("T = 50", "T = 20").replace('[costs.effort]\ntype = "control"\nweight = 1e-3',
                                                   '[costs.hold]\ntype = "control"\ntarget = "gravity"\n'
                                                   'weight = [1e-3, 1e-2, 1e-2, 2e-2, 3e-2, 5e-2]')
    if box:
        text += '\n[costs.limit]\ntype = "control_limit"\nweight = 1e2\n'
    path = tmp_path / f"hold{'_box' if box else ''}.toml"
    path.write_text(text)
    return path


def raico_problem(path: Path):
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


def term_costs(cp, X, U) -> dict[str, float]:
    """Each raico term's total as crocoddyl computes it."""
    out: dict[str, float] = {}
    Xp, Up = cp.to_pin(X), cp.controls_to_pin(U)
    for t in range(cp.T + 1):
        m = cp.shooting.runningModels[t] if t < cp.T else cp.shooting.terminalModel
        d = m.createData()
        m.calc(d, Xp[t], Up[t]) if t < cp.T else m.calc(d, Xp[t])
        weights = {k: c.weight for k, c in m.differential.costs.costs.todict().items()}
        for key, item in d.differential.costs.costs.todict().items():
            name = key.split("/")[0]
            out[name] = out.get(name, 0.0) + (cp.dt if t < cp.T else 1.0) * weights[key] * item.cost
    return out


def test_the_fixture_damps_every_joint_and_has_a_prismatic_lift():
    from raico.planning.problem_file import read_problem
    from raico.plants.model_file import shared_model
    from raico.stages.evaluate.metrics import prismatic_joints

    robot = shared_model(read_problem(DATA / "lift6_reach.toml").robot_spec())
    assert robot.n_q == 6 and prismatic_joints(robot).tolist() == [True] + [False] * 5
    pmodel, _ = cm.pinocchio_robot(robot, "angle")
    assert np.all(np.asarray(pmodel.damping) > 0)


@pytest.mark.parametrize("box", [False, True])
def test_control_toward_gravity_on_a_damped_model_costs_and_derives_as_raico(tmp_path, box):
    robot, problem = raico_problem(hold_problem(tmp_path, box))
    assert [type(t).__name__ for t in problem.joint_terms] == ["ControlGravity"]
    cp = cm.build(problem)   # once refused: "the model file damps its joints"
    rng = np.random.default_rng(3)
    T, n = problem.T, problem.n_u
    X = np.tile(problem.x0, (T + 1, 1))
    X[:, :n] += 0.1 * rng.standard_normal((T + 1, n))
    X[:, n:] += rng.standard_normal((T + 1, n))   # velocities: the damping torque D v is not small
    U = 20.0 * rng.standard_normal((T, n))
    raico_terms, croc_terms = problem.cost_terms(X, U), term_costs(cp, X, U)
    assert croc_terms.keys() == raico_terms.keys() and "hold" in raico_terms
    for name, c in raico_terms.items():
        assert c > 0 and abs(croc_terms[name] - c) <= RTOL * c, (name, croc_terms[name], c)
    # crocoddyl's own residual (on the actuation's torque u - D v) would cost the hold term otherwise
    D = np.asarray(cp.pmodel.damping)[cp.smap.v_index]
    assert np.abs(D[None] * X[:-1, n:]).max() > 0.1
    problem.set_nominal(X, U)
    lu, luu = problem.control_derivatives(U)
    v = cp.smap.v_index
    for t in (0, 7):
        m = cp.shooting.runningModels[t]
        d = m.createData()
        x, u = cp.smap.x_to_pin(X[t]), cp.smap.u_to_pin(U[t])
        m.calc(d, x, u)
        m.calcDiff(d, x, u)
        lx, lxx = problem.point_state_derivatives(X[t], t)
        idx = cp.smap.tangent_index
        for croc, ref in ((np.asarray(d.Lu)[v], lu[t]), (np.asarray(d.Luu)[np.ix_(v, v)], luu[t]),
                          (np.asarray(d.Lx)[idx], lx), (np.asarray(d.Lxx)[np.ix_(idx, idx)], lxx)):
            assert np.abs(ref).max() > 0
            np.testing.assert_allclose(croc, ref, rtol=RTOL, atol=RTOL * np.abs(ref).max())


def test_the_residual_on_the_control_by_finite_differences():
    """The residual ``u - g(q)``'s Jacobians against central differences (a step of 1e-6 in q: the error
    is the truncation ``h^2 g'''`` and the rounding ``eps |g| / h``, both below 1e-6 of ``|dg/dq|``)."""
    import crocoddyl

    from raico.planning.crocoddyl.costs import ControlGravityResidual
    from raico.planning.problem_file import read_problem
    from raico.plants.model_file import shared_model

    robot = shared_model(read_problem(DATA / "lift6_reach.toml").robot_spec())
    pmodel, smap = cm.pinocchio_robot(robot, "angle")
    state = crocoddyl.StateMultibody(pmodel)
    res = ControlGravityResidual(state, state.nv)
    data = res.createData(crocoddyl.DataCollectorAbstract())
    rng = np.random.default_rng(0)
    x = np.concatenate([np.clip(robot.default_q + 0.3 * rng.standard_normal(6), robot.lower, robot.upper),
                        rng.standard_normal(6)])
    u = rng.standard_normal(6)
    res.calc(data, x, u)
    res.calcDiff(data, x, u)
    Rx, Ru, h = np.array(data.Rx), np.array(data.Ru), 1e-6

    def r(xx, uu):
        d = res.createData(crocoddyl.DataCollectorAbstract())
        res.calc(d, xx, uu)
        return np.array(d.r)

    fd = np.column_stack([(r(x + h * e, u) - r(x - h * e, u)) / (2 * h) for e in np.eye(12)])
    np.testing.assert_allclose(Rx, fd, rtol=1e-6, atol=1e-6 * np.abs(Rx).max())
    np.testing.assert_array_equal(Ru, np.eye(6))
    assert np.abs(Rx[:, 6:]).max() == 0   # no velocity term: the damping is not the control's


@pytest.mark.parametrize("solver_box", ["no", "yes"])
def test_fddp_and_boxfddp_plan_the_damped_hold(tmp_path, solver_box):
    """FDDP (box no) and BoxFDDP (box yes) solve the damped problem: a finite plan whose cost fell."""
    from raico.planning.crocoddyl import FDDPOptions, fddp

    _, problem = raico_problem(hold_problem(tmp_path, box=solver_box == "yes"))
    res = fddp(problem, FDDPOptions(iterations=5, box=solver_box, start="rollout"))
    assert res.status != "diverged" and np.all(np.isfinite(res.X)) and np.all(np.isfinite(res.U))
    assert problem.cost(res.X, res.U) < res.initial_cost   # from the feasible zero-torque rollout, descent
