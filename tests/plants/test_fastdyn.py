"""FastAnalyticDynamics (raico.plants.fast_analytic, code from raico.plants.codegen) against
AnalyticDynamics (AutoDiffXd) and Drake's time derivatives: the verification of the fast route.
Its linearization against finite differences: ``tests/plants/test_derivatives.py``."""

from types import SimpleNamespace

import numpy as np
import pytest

from raico.plants.codegen.derive import compiled_dynamics, is_supported, self_check
from raico.plants.codegen.drake_reader import cyclic_positions
from raico.plants.codegen.emit import emit
from raico.plants.codegen.graph import Graph
from raico.plants.dynamics import AnalyticDynamics, rollout
from raico.plants.fast_analytic import FastAnalyticDynamics, make_fast_or_exact
from raico.plants.numdiff import numdiff_jacobian
from raico.plants.robots import shared_robot
from tests.tolerance import REL, assert_close, scale_of

pytestmark = pytest.mark.compiled   # reaches a C kernel: run under the sanitizers too

NAMES = ["pendulum", "arm5", "biorob"]
DT = 0.01


def random_states(robot, T, seed):
    """Postures over a wide range (full turns on the first joints), brisk velocities, torques."""
    rng = np.random.default_rng(seed)
    n = robot.n_q
    Q = robot.default_q + rng.uniform(-1.5, 1.5, (T, n))
    X = np.concatenate([Q, 2.0 * rng.standard_normal((T, n))], axis=1)
    U = 3.0 * rng.standard_normal((T, n))
    return X, U


def close(got, ref, rtol=REL):
    """Relative agreement, scaled by the reference's largest entry (``tests/tolerance.py``)."""
    assert_close(got, ref, rel=rtol)


@pytest.fixture(scope="module", params=NAMES)
def pair(request):
    r = shared_robot(request.param)
    return r, FastAnalyticDynamics(r, DT), AnalyticDynamics(r, DT)


@pytest.mark.numerics
def test_interface_matches_analytic(pair):
    r, fast, exact = pair
    for attr in ("n_q", "n_x", "n_u", "dt"):
        assert getattr(fast, attr) == getattr(exact, attr)
    assert fast.robot is r and np.array_equal(fast.P, exact.P)


@pytest.mark.numerics
def test_step_qddot_and_inverse_dynamics_equal_analytic(pair):
    r, fast, exact = pair
    X, U = random_states(r, 6, seed=1)
    n = r.n_q
    for x, u in zip(X, U):
        q, v = x[:n], x[n:]
        close(fast.qddot(q, v, u), exact.qddot(q, v, u))
        close(fast.inverse_dynamics(q, v, u), exact.inverse_dynamics(q, v, u))
        close(fast.step(x, u), exact.step(x, u))
        for got, ref in zip(fast.qddot_derivatives(q, v, u), exact.qddot_derivatives(q, v, u)):
            close(got, ref)
    close(fast.qddot_trajectory(X[:, :n], X[:, n:], U),
          np.stack([exact.qddot(x[:n], x[n:], u) for x, u in zip(X, U)]))
    close(fast.step_trajectory(X, U), np.stack([exact.step(x, u) for x, u in zip(X, U)]))


@pytest.mark.numerics
def test_linearize_equals_analytic(pair):
    r, fast, exact = pair
    X, U = random_states(r, 5, seed=2)
    for x, u in zip(X, U):
        A, a, B = fast.linearize(x, u)
        A0, a0, B0 = exact.linearize(x, u)
        close(A, A0)
        close(B, B0)
        # the offset is a small difference of large terms: compare on the scale of the step
        assert_close(a, a0, scale=1 + scale_of(x) + scale_of(u))
        assert_close(A @ x + a + B @ u, exact.step(x, u), scale=scale_of(x, u))


@pytest.mark.numerics
def test_linearize_trajectory_equals_analytic_and_pointwise(pair):
    r, fast, exact = pair
    X, U = random_states(r, 40, seed=3)
    A, a, B = fast.linearize_trajectory(X, U)
    A0, a0, B0 = exact.linearize_trajectory(X, U)
    assert A.shape == (40, r.n_x, r.n_x) and a.shape == (40, r.n_x) and B.shape == (40, r.n_x, r.n_q)
    close(A, A0)
    close(B, B0)
    assert_close(a, a0, scale=1 + scale_of(X) + scale_of(U))
    # the batched path and the single-point path give the same numbers
    for t in (0, 17, 39):
        A1, a1, B1 = fast.linearize(X[t], U[t])
        close(A[t], A1)
        close(B[t], B1)
        assert_close(a[t], a1, scale=1 + scale_of(X[t], U[t]))


@pytest.mark.numerics
def test_qddot_matches_drake_time_derivatives(pair):
    r, fast, _ = pair
    X, U = random_states(r, 3, seed=5)
    n = r.n_q
    ctx = r.plant.CreateDefaultContext()
    for x, u in zip(X, U):
        r.plant.SetPositions(ctx, r.to_plant_q(x[:n]))
        r.plant.SetVelocities(ctx, r.to_plant_q(x[n:]))
        r.plant.get_actuation_input_port().FixValue(ctx, r.actuation(u))
        xdot = r.plant.EvalTimeDerivatives(ctx).CopyToVector()
        np.testing.assert_allclose(fast.qddot(x[:n], x[n:], u), xdot[n:], rtol=0, atol=1e-9)


@pytest.mark.numerics
def test_rollout_equals_analytic(pair):
    r, fast, exact = pair
    X, U = random_states(r, 30, seed=6)
    U = 0.3 * U
    close(rollout(fast, X[0], U), rollout(exact, X[0], U))


@pytest.mark.numerics
def test_build_self_check_and_cache():
    r = shared_robot("arm5")
    code = compiled_dynamics(r)
    assert compiled_dynamics(r) is code  # cached per plant name
    assert self_check(r.plant, code, n_states=2, seed=7) <= REL
    # the base yaw is vertical: its angle was eliminated, and derivatives along it are exact 0
    assert code.stats["cyclic_positions"] == [r.plant.GetJointByName("base_yaw").position_start()]
    fast = FastAnalyticDynamics(r, DT)
    X, U = random_states(r, 3, seed=8)
    A, _, _ = fast.linearize_trajectory(X, U)
    n = r.n_q
    assert np.all(A[:, n:, 0] == 0) and np.all(A[:, :n, 0] == np.eye(n)[0])


def test_cyclic_positions():
    assert cyclic_positions(shared_robot("pendulum").plant) == []  # horizontal axis
    assert cyclic_positions(shared_robot("biorob").plant) == [0]


def test_fallback_for_the_nao():
    nao = shared_robot("nao")
    assert not is_supported(nao)
    with pytest.raises(NotImplementedError,
                       match=r"^nao: 26 tree joints: symbolic dynamics too large \(max 12\)$"):
        FastAnalyticDynamics(nao, DT)
    # the compiled kinematic-tree model where the C route exists, AutoDiffXd where it does not
    from raico.plants.codegen.c_backend import enabled as compiler_available
    from raico.plants.fast_analytic import TreeAnalyticDynamics

    expected = TreeAnalyticDynamics if compiler_available() else AnalyticDynamics
    assert type(make_fast_or_exact(nao, DT)) is expected
    assert type(make_fast_or_exact(shared_robot("arm5"), DT)) is FastAnalyticDynamics


@pytest.mark.numerics
def test_graph_simplifies_and_differentiates():
    g = Graph()
    x, y = g.x(0), g.x(1)
    assert g.add(x, g.zero) == x and g.mul(x, g.one) == x and g.mul(x, g.zero) == g.zero
    assert g.sub(x, x) == g.zero and g.neg(g.neg(x)) == x
    assert g.add(g.mul(x, y), g.mul(y, x)) == g.add(g.mul(y, x), g.mul(x, y))  # hash-consed
    f = g.div(g.mul(g.unary("sin", x), g.pow(y, 3.0)), g.add(g.unary("cos", y), g.const(2.0)))
    src = emit(g, "f", [x, y], [f, g.diff(f, 0), g.diff(f, 1)])
    ns = {"sin": np.sin, "cos": np.cos, "sqrt": np.sqrt}
    exec(src, ns)
    p = np.array([0.7, -1.3])

    def fn(z):
        return np.sin(z[0]) * z[1] ** 3 / (np.cos(z[1]) + 2.0)

    val, dx, dy = ns["f"](list(p), [0.0] * 3)
    assert val == pytest.approx(fn(p), rel=1e-9)
    np.testing.assert_allclose([dx, dy], numdiff_jacobian(fn, p)[0], rtol=1e-8)


def test_bad_shapes_are_refused():
    fast = FastAnalyticDynamics(shared_robot("arm5"), DT)
    with pytest.raises(ValueError, match=r"^X \(3, 10\), U \(4, 5\): expected \(T, 10\), \(T, 5\)$"):
        fast.linearize_trajectory(np.zeros((3, 10)), np.zeros((4, 5)))
    with pytest.raises(ValueError, match=r"^X \(3, 9\), U \(3, 5\): expected \(T, 10\), \(T, 5\)$"):
        fast.step_trajectory(np.zeros((3, 9)), np.zeros((3, 5)))
    with pytest.raises(ValueError, match=r"^P has shape \(4, 4\), the plant has 5 positions$"):
        FastAnalyticDynamics(SimpleNamespace(name="arm5", plant=shared_robot("arm5").plant,
                                             P=np.eye(4), n_q=4), DT)


@pytest.mark.numerics
def test_a_plant_with_other_parameters_gets_its_own_code():
    from raico.plants import robots

    code = compiled_dynamics(shared_robot("pendulum"))
    assert FastAnalyticDynamics(robots.load_robot("pendulum"), DT)._code is code
    from dataclasses import replace

    from raico.plants.model_file import load_model

    other = load_model(replace(robots.builtin_spec("pendulum"), armature=0.2))  # a motor on the pendulum
    fast = FastAnalyticDynamics(other, DT)
    assert fast._code is not code
    q, v, u = np.array([0.4]), np.array([1.0]), np.array([0.5])
    close(fast.qddot(q, v, u), AnalyticDynamics(other, DT).qddot(q, v, u))
    assert abs(fast.qddot(q, v, u)[0] - FastAnalyticDynamics(shared_robot("pendulum"), DT).qddot(
        q, v, u)[0]) > 1e-3


@pytest.mark.numerics
@pytest.mark.parametrize("kind", ["symbolic", "tree"])
def test_coupled_joints_through_P_equal_analytic(kind):
    """A reduced model (two arm joints driven by one coordinate, as the Nao's hips; the tree route also
    with a coupling of another ratio) gives the numbers of AnalyticDynamics on the same coupling map."""
    from raico.plants.fast_analytic import TreeAnalyticDynamics

    arm = shared_robot("arm5")
    P = np.zeros((5, 4))
    P[[0, 1, 2, 3, 4], [0, 1, 2, 2, 3]] = 1.0  # elbow and wrist pitch move together
    if kind == "tree":
        P[3, 2] = -0.5   # the wrist at minus half the elbow's angle
    r = SimpleNamespace(name=arm.name, plant=arm.plant, P=P, n_q=4)
    fast = (FastAnalyticDynamics if kind == "symbolic" else TreeAnalyticDynamics)(r, DT)
    exact = AnalyticDynamics(r, DT)
    rng = np.random.default_rng(9)
    X = np.concatenate([rng.uniform(-1.5, 1.5, (6, 4)), rng.standard_normal((6, 4))], axis=1)
    U = rng.standard_normal((6, 4))
    A, a, B = fast.linearize_trajectory(X, U)
    A0, a0, B0 = exact.linearize_trajectory(X, U)
    assert_close(A, A0)
    assert_close(B, B0)
    assert_close(a, a0, scale=1 + scale_of(X))
    assert_close(fast.step(X[0], U[0]), exact.step(X[0], U[0]), scale=scale_of(X[0], U[0]))
    for got, ref in zip(fast.linearize(X[1], U[1]), (A0[1], a0[1], B0[1])):
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9 * max(1.0, np.max(np.abs(ref))))


@pytest.mark.numerics
def test_derived_code_is_kept_on_disk_and_checked_when_loaded(tmp_path, monkeypatch):
    """A new process loads the derived code from the kernel cache (the same code a derivation gives);
    a damaged file or one whose code disagrees with Drake is ignored and replaced by a new derivation."""
    import json

    from raico.plants.codegen import derive as dv

    monkeypatch.setenv("RAICO_KERNEL_DIR", str(tmp_path))
    monkeypatch.setattr(dv, "_COMPILED", {})
    r = shared_robot("biorob")
    fresh = compiled_dynamics(r)
    (path,) = tmp_path.glob("derived-biorob-*.json")
    monkeypatch.setattr(dv, "_COMPILED", {})  # as in a new process
    calls = []
    monkeypatch.setattr(dv, "derive", lambda plant: calls.append(1) or fresh)
    loaded = compiled_dynamics(r)
    assert calls == [] and loaded is not fresh
    assert loaded.source == fresh.source and loaded.c_source == fresh.c_source
    assert self_check(r.plant, loaded, n_states=2, seed=3) <= REL

    doc = json.loads(path.read_text())
    doc["c_source"] += " "  # damaged: the checksum no longer matches
    path.write_text(json.dumps(doc))
    monkeypatch.setattr(dv, "_COMPILED", {})
    assert compiled_dynamics(r) is fresh and calls == [1]
    # code that disagrees with Drake (a checksum that matches it): the self-check refuses it
    doc = json.loads(path.read_text())
    doc.pop("sha256")
    doc["sources"]["first"] = doc["sources"]["first"].replace("    return out\n", "    out[0] += 1.0\n    return out\n")
    doc["sha256"] = dv.derived_digest(doc)
    path.write_text(json.dumps(doc))
    monkeypatch.setattr(dv, "_COMPILED", {})
    assert dv.load_derived(r.plant, path) is None
    assert compiled_dynamics(r) is fresh and calls == [1, 1]


@pytest.mark.numerics
@pytest.mark.parametrize("kind", ["symbolic", "tree"])
def test_dynamics_library_flags_keep_every_bit(kind, monkeypatch):
    """The dynamics libraries' -O3 (raico.plants.fast_analytic.DYN_FLAGS) vectorizes without contraction or
    reassociation: the linearization equals the -O2 build's bit for bit."""
    import raico.plants.fast_analytic as fa
    from raico.plants.codegen import c_backend

    robot = shared_robot("arm5")
    make = fa.FastAnalyticDynamics if kind == "symbolic" else fa.TreeAnalyticDynamics
    rng = np.random.default_rng(5)
    X = np.concatenate([robot.default_q + rng.standard_normal((9, robot.n_q)), rng.standard_normal((9, robot.n_q))], 1)
    U = 5.0 * rng.standard_normal((9, robot.n_q))
    fast = make(robot, 0.01)._compiled()
    if fast is None:
        pytest.skip("no compiler")
    assert "-O3" in fa.DYN_FLAGS
    monkeypatch.setattr(fa, "DYN_FLAGS", c_backend.CFLAGS)
    plain = make(robot, 0.01)._compiled()
    assert plain.lib is not fast.lib
    for s, t in zip(plain.linearize_trajectory(X, U), fast.linearize_trajectory(X, U)):
        assert np.array_equal(s, t)
