"""A continuous joint's angle as (sin, cos) GP inputs: gradients against central differences, the
linearization of the learned dynamics through them, invariance under full turns, storage."""

from __future__ import annotations

import numpy as np
import pytest

from raico.plants.gp import AngleInputGP, GPModel, angle_features, angle_jacobian
from raico.plants.learned import LearnedDynamics, build_learned
from tests.tolerance import assert_close

WRAP = np.array([1])   # a cart-pole's inputs (x, theta, xdot, thetadot, u): theta is column 1


def cartpole_like_gp(n: int = 40, seed: int = 0) -> AngleInputGP:
    """An exact GP over the angle features of 5 raw inputs, 2 outputs, fixed hyperparameters."""
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.uniform(-1, 1, n), rng.uniform(-8, 8, n), rng.normal(0, 1, (n, 2)),
                         rng.uniform(-10, 10, n)])
    Y = np.column_stack([X[:, 4] + np.sin(X[:, 1]) * X[:, 3] ** 2, -9.81 * np.sin(X[:, 1]) - np.cos(X[:, 1]) * X[:, 4]])
    F = angle_features(X, WRAP)
    return AngleInputGP(GPModel(F, Y, np.full((2, F.shape[1]), 1.2), np.ones(2), np.full(2, 1e-3)), WRAP)


def queries(m: int = 5, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-1, 1, m), rng.uniform(-8, 8, m), rng.normal(0, 1, (m, 2)),
                            rng.uniform(-10, 10, m)])


def central(f, X: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """``d f / d X`` ``(M, D, d)`` of ``f: (M, d) -> (M, D)`` by central differences."""
    cols = []
    for c in range(X.shape[1]):
        E = np.zeros_like(X)
        E[:, c] = h
        cols.append((f(X + E) - f(X - E)) / (2 * h))
    return np.stack(cols, axis=-1)


def test_features_and_their_jacobian():
    X = queries()
    F = angle_features(X, WRAP)
    assert F.shape == (5, 6)
    assert_close(F[:, 1], np.sin(X[:, 1]))
    assert_close(F[:, 5], np.cos(X[:, 1]))
    assert np.array_equal(np.delete(F, [1, 5], axis=1), np.delete(X, 1, axis=1))
    # central differences of a smooth map: truncation h^2 |f'''| / 6 and rounding eps |f| / h, both < 1e-8
    assert_close(angle_jacobian(X, WRAP), central(lambda Z: angle_features(Z, WRAP), X), rel=1e-8, scale=1.0)


def test_gradients_match_central_differences_batch_and_point():
    gp, X = cartpole_like_gp(), queries()
    m, v, dm, dv = gp.predict_with_gradients(X)
    m0, v0 = gp.predict(X)
    assert_close(m, m0)
    assert_close(v, v0)
    m1, dm1 = gp.mean_with_gradients(X)
    assert_close(dm1, dm)
    # step 1e-6 on inputs of scale <= 10 and length-scales ~1: truncation ~1e-12, rounding ~eps |m| / h ~ 1e-9 |m|
    assert_close(dm, central(gp.predict_mean, X), rel=1e-6, scale=float(np.abs(m).max()))
    assert_close(dv, central(lambda Z: gp.predict(Z)[1], X), rel=1e-6, scale=float(np.abs(v).max()))
    for x, mm, g, vv, gv in zip(X, m, dm, v, dv):
        pm, pg = gp.point_mean_with_gradients(x)
        assert_close(pm, mm)
        assert_close(pg, g)
        qm, qv, qg, qgv = gp.point_predict_with_gradients(x)
        assert_close(qm, mm)
        assert_close(qv, vv)
        assert_close(qg, g)
        assert_close(qgv, gv)


def test_a_full_turn_is_the_same_input_and_nan_stays_nan():
    gp, X = cartpole_like_gp(), queries()
    turned = X.copy()
    turned[:, 1] += 2 * np.pi * np.array([1, -1, 3, 2, -4])
    m, v = gp.predict(X)
    mt, vt = gp.predict(turned)
    # sin/cos of theta + 2 pi k differ from sin/cos theta by ~k eps 4 pi: the GP's condition amplifies that
    assert_close(mt, m, rel=1e-9, scale=1.0)
    assert_close(vt, v, rel=1e-9, scale=1.0)
    X[0, 1] = np.nan
    assert np.all(np.isnan(gp.predict_mean(X)[0])) and np.all(np.isfinite(gp.predict_mean(X)[1:]))


def test_stored_and_loaded_through_gpmodel_from_arrays():
    gp, X = cartpole_like_gp(), queries()
    back = GPModel.from_arrays(gp.to_arrays())
    assert isinstance(back, AngleInputGP) and back.d == 5 and back.inner.d == 6
    assert_close(back.predict_mean(X), gp.predict_mean(X))
    assert back.point_linearizer(0.1) is None and back.controller_rollout(X[0, :4], np.zeros((3, 1)),
                                                                          np.zeros((3, 1, 4)), 0.1) is None
    with pytest.raises(ValueError):
        AngleInputGP(gp.inner, np.array([5]))   # the angle column must be among the raw inputs


def test_learned_dynamics_linearize_through_the_features():
    gp = cartpole_like_gp()
    dyn = build_learned(type("R", (), {"n_q": 2})(), 0.1, gp.to_arrays())
    assert isinstance(dyn, LearnedDynamics) and dyn.c_linearizer() is None
    X, U = queries(4)[:, :4], queries(4)[:, 4:]
    At, at, Bt = dyn.linearize_trajectory(X, U)
    for t in range(len(X)):
        A, a, B = dyn.linearize(X[t], U[t])
        assert_close(A, At[t])
        assert_close(a, at[t], scale=float(np.abs(X).max()))
        assert_close(B, Bt[t])
        x, u = X[t][None], U[t][None]
        fd_A = central(lambda Z, u=u: dyn.step_batch(Z, np.repeat(u, len(Z), 0)), x)[0]
        fd_B = central(lambda W, x=x: dyn.step_batch(np.repeat(x, len(W), 0), W), u)[0]
        assert_close(A, fd_A, rel=1e-6, scale=1.0)
        assert_close(B, fd_B, rel=1e-6, scale=1.0)
        # affine and exact at the point: A x + a + B u is the step
        assert_close(A @ X[t] + a + B @ U[t], dyn.step(X[t], U[t]), scale=float(np.abs(X).max()))


def test_continuous_joints_are_found_and_limited_ones_are_not():
    from raico.plants.robots import shared_robot
    from raico.stages.fit.stage import angle_inputs

    assert angle_inputs(shared_robot("cartpole")) == (1,)   # the pole: a URDF continuous joint
    assert angle_inputs(shared_robot("pendulum")) == ()     # +-100 rad: a limited revolute joint keeps its angle
