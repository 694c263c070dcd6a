"""Every registered derivative against finite differences (raico.plants.numdiff), automatically:

- every dynamics model in ``raico.plants.dynamics_registry.DYNAMICS`` on every plant (models that need fitted
  parameters are listed and skipped here; their own tests fit them);
- every task map example in ``raico.plants.taskmaps.TASKMAP_EXAMPLES`` on every plant it applies to;
- every cost term example in ``raico.planning.costs.COST_TERM_EXAMPLES`` on every plant it applies to.

A model, task map or cost term is checked the moment it is registered. The last tests show
that each check can fail, and that every class has an example.
"""

from __future__ import annotations

import inspect

import numpy as np
import pytest

import raico.planning.costs as costs_module
import raico.plants.taskmaps as taskmaps_module
from raico.planning.costs import COST_TERM_EXAMPLES, ControlCost, ControlTerm, StateTerm, ViaPoint
from raico.plants.dynamics import PseudoDynamics
from raico.plants.dynamics_registry import DYNAMICS, make_dynamics
from raico.plants.numdiff import (
    check_cost_term,
    check_dynamics,
    check_jacobian,
    check_taskmap,
    compare,
    numdiff_jacobian,
)
from raico.plants.robots import PLANTS, shared_robot
from raico.plants.taskmaps import TASKMAP_EXAMPLES, JointPositions

pytestmark = pytest.mark.compiled   # reaches a C kernel: run under the sanitizers too

DT = 0.01


def dynamics_points(robot, seed: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Two states ``(2, n_x)`` and torques ``(2, n_u)``: near the default posture, and wide
    (joints 1.5 rad off, brisk velocities, large torques)."""
    rng = np.random.default_rng(seed)
    n = robot.n_q
    near = np.concatenate([robot.default_q + 0.1 * rng.standard_normal(n), 0.5 * rng.standard_normal(n)])
    wide = np.concatenate([robot.default_q + rng.uniform(-1.5, 1.5, n), 2.0 * rng.standard_normal(n)])
    return np.stack([near, wide]), np.stack([rng.standard_normal(n), 3.0 * rng.standard_normal(n)])


def positions(robot, K: int = 3, seed: int = 4) -> np.ndarray:
    """``K`` postures ``(K, n_q)`` around the default one (0.1 rad and 0.3 rad spreads)."""
    rng = np.random.default_rng(seed)
    spread = np.linspace(0.1, 0.3, K)[:, None]
    return robot.default_q + spread * rng.standard_normal((K, robot.n_q))


def _dynamics_cases() -> list:
    return [pytest.param(kind, plant, id=f"{kind}-{plant}") for kind in DYNAMICS for plant in PLANTS]


@pytest.mark.numerics
@pytest.mark.parametrize("kind,plant", _dynamics_cases())
def test_dynamics_linearization(kind, plant):
    """Models that need fitted parameters are checked with their registered example set."""
    robot = shared_robot(plant)
    spec = DYNAMICS[kind]
    params = spec.example_params(robot) if spec.needs_params else None
    X, U = dynamics_points(robot)
    check_dynamics(make_dynamics(kind, robot, DT, params), X, U).assert_passed()


@pytest.mark.numerics
@pytest.mark.parametrize("name,plant", [(n, p) for n, ex in TASKMAP_EXAMPLES.items()
                                        for p in PLANTS if ex.applies_to(p)])
def test_taskmap_jacobian(name, plant):
    robot = shared_robot(plant)
    check_taskmap(TASKMAP_EXAMPLES[name].build(robot), positions(robot)).assert_passed()


def _check_cost_example(term, kind: str, robot, exact_hessian: bool, seed: int = 5):
    rng = np.random.default_rng(seed)
    if kind == "joint":  # state part at the nominal controls, control part at the nominal states
        Q = positions(robot, K=4, seed=seed)
        X = np.concatenate([Q, 0.5 * rng.standard_normal(Q.shape)], axis=1)
        U = rng.standard_normal((4, robot.n_q))
        term.set_nominal(np.vstack([X, X[-1:]]), U)
        state = check_cost_term(lambda Z: term.value(Z), lambda Z: term.derivatives(Z), X,
                                exact_hessian=exact_hessian, subject=term.name)
        control = check_cost_term(term.control_value, term.control_derivatives, U, exact_hessian=exact_hessian,
                                  what="u", subject=term.name)
        for c in control.checks:
            state.checks.append(c)
        return state
    if kind == "state":
        Q = positions(robot, K=5, seed=seed)
        X = np.concatenate([Q, rng.standard_normal(Q.shape)], axis=1)
        idx = np.arange(len(X))  # some rows active (EXAMPLE_TIMES), some not
        return check_cost_term(lambda Z: term.value(Z, idx), lambda Z: term.derivatives(Z, idx), X,
                               exact_hessian=exact_hessian, subject=term.name)
    U = rng.standard_normal((5, robot.n_q))
    return check_cost_term(term.value, term.derivatives, U, exact_hessian=exact_hessian, what="u",
                           subject=term.name)


@pytest.mark.numerics
@pytest.mark.parametrize("name,plant", [(n, p) for n, ex in COST_TERM_EXAMPLES.items()
                                        for p in PLANTS if ex.applies_to(p)])
def test_cost_term_derivatives(name, plant):
    ex = COST_TERM_EXAMPLES[name]
    robot = shared_robot(plant)
    term = ex.build(robot, robot.default_q.copy())
    _check_cost_example(term, ex.kind, robot, ex.exact_hessian).assert_passed()


# -- the checks can fail ------------------------------------------------------------------------
class _WrongB(PseudoDynamics):
    """Pseudo-dynamics whose ``B`` is off by 1e-4 in one entry (``step`` is right; ``a`` and
    ``linearize_trajectory`` are consistent with the wrong ``B``)."""

    def linearize(self, x, u):
        A, _, B = super().linearize(x, u)
        B[0, 0] += 1e-4
        return A, self.step(x, u) - A @ x - B @ u, B

    def linearize_trajectory(self, X, U):
        parts = [self.linearize(x, u) for x, u in zip(X, U)]
        return tuple(np.stack([p[i] for p in parts]) for i in range(3))


class _WrongJacobian(JointPositions):
    def value_and_jacobian(self, q):
        v, J = super().value_and_jacobian(q)
        return v, 1.001 * J

    def values_and_jacobians(self, Q):
        V, J = super().values_and_jacobians(Q)
        return V, 1.001 * J


@pytest.mark.numerics
def test_checks_fail_on_wrong_derivatives():
    f = lambda x: np.array([np.sin(x[0]) * x[1], x[1] ** 2])  # noqa: E731
    x = np.array([0.3, -1.2])
    J = np.array([[np.cos(0.3) * -1.2, np.sin(0.3)], [0.0, -2.4]])
    assert check_jacobian("right", J, f, x)
    wrong = J.copy()
    wrong[1, 1] += 1e-5
    bad = check_jacobian("wrong", wrong, f, x)
    assert not bad and bad.worst == (1, 1) and bad.max_abs_error == pytest.approx(1e-5, rel=1e-3)
    assert not compare("shape", J[:1], J, 1.0) and not compare("nan", J * np.nan, J, 1.0)

    X, U = dynamics_points(shared_robot("arm5"))
    report = check_dynamics(_WrongB(5, DT), X, U)
    assert not report and {c.name for c in report.failures} == {"B[0] vs FD", "B[1] vs FD"}
    with pytest.raises(AssertionError, match="B\\[0\\] vs FD: FAILED"):
        report.assert_passed()

    report = check_taskmap(_WrongJacobian(3, [0, 2]), np.ones((2, 3)))
    assert [c.name for c in report.failures] == ["J vs FD"]

    term = ControlCost(0.5)
    report = check_cost_term(term.value, lambda U: (1.01 * term.derivatives(U)[0], term.derivatives(U)[1]),
                             np.ones((2, 3)), what="u")
    assert [c.name for c in report.failures] == ["l_u vs FD"]
    report = check_cost_term(term.value, lambda U: (term.derivatives(U)[0], -term.derivatives(U)[1]),
                             np.ones((2, 3)), what="u")
    assert [c.name for c in report.failures] == ["l_uu positive semi-definite"]


@pytest.mark.numerics
def test_numdiff_jacobian_shapes():
    x = np.array([1.0, -2.0, 0.5])
    np.testing.assert_allclose(numdiff_jacobian(lambda z: z @ z, x), [2 * x], rtol=1e-8)  # (1, 3)
    x = np.arange(3.0)
    J = numdiff_jacobian(lambda z: np.outer(z, z), x)
    # d(x_i x_j)/dx_k = delta_ik x_j + delta_jk x_i
    eye = np.eye(3)
    want = np.einsum("ik,j->ijk", eye, x) + np.einsum("jk,i->ijk", eye, x)
    assert J.shape == (3, 3, 3)
    np.testing.assert_allclose(J, want, rtol=0, atol=1e-8)


# -- every class has an example ------------------------------------------------------------------
def _classes(module, base=None):
    return {c for _, c in inspect.getmembers(module, inspect.isclass)
            if c.__module__ == module.__name__ and not c.__name__.startswith("_")
            and (base is None or (issubclass(c, base) and c is not base))}


def test_every_taskmap_class_has_an_example():
    maps = {type(ex.build(shared_robot("arm5"))) for ex in TASKMAP_EXAMPLES.values()
            if ex.applies_to("arm5")}
    classes = {c for c in _classes(taskmaps_module) if hasattr(c, "values_and_jacobians")
               and c is not taskmaps_module.TaskMap}
    assert classes <= maps, f"task map classes without an example: {classes - maps}"


def test_every_cost_term_class_has_an_example():
    robot = shared_robot("arm5")
    built = {type(ex.build(robot, robot.default_q)) for ex in COST_TERM_EXAMPLES.values()
             if ex.applies_to("arm5")}
    classes = (_classes(costs_module, StateTerm) | _classes(costs_module, ControlTerm)
               | {costs_module.Uncertainty, costs_module.ControlGravity})
    assert classes <= built, f"cost term classes without an example: {classes - built}"
    via = {name for name in COST_TERM_EXAMPLES if name.startswith("via_")}
    assert via == {f"via_{name}" for name in TASKMAP_EXAMPLES}  # a via-point on every task map
    assert all(isinstance(COST_TERM_EXAMPLES[name].build(robot, robot.default_q), ViaPoint)
               for name in via if COST_TERM_EXAMPLES[name].applies_to("arm5"))


@pytest.mark.numerics
@pytest.mark.parametrize("name", sorted(TASKMAP_EXAMPLES))
def test_taskmap_batch_of_non_finite_rows_is_nan(name):
    """A diverged trajectory (no finite row) gives NaN values and Jacobians, not an error."""
    robot = shared_robot("arm5")
    ex = TASKMAP_EXAMPLES[name]
    if not ex.applies_to("arm5"):
        pytest.skip("not an arm5 task map")
    tm = ex.build(robot)
    V, J = tm.values_and_jacobians(np.full((3, robot.n_q), np.nan))
    assert V.shape == (3, tm.dim) and J.shape == (3, tm.dim, robot.n_q) and np.isnan(V).all()
