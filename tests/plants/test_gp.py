"""GP posterior (raico.plants.gp), fitting (raico.stages.fit.gp_fit) and learned dynamics (raico.plants.learned): small, fast."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.linalg import solve_triangular
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

from raico.plants.dynamics import Dynamics
from raico.plants.gp import NOISE_FLOOR, GPModel
from raico.plants.learned import LearnedDynamics, build_learned
from raico.stages.fit.gp_fit import fit_gp, measure_cap_cost, refit_fixed, subsample_indices
from tests.tolerance import REL, bound, close, scale_of

pytestmark = pytest.mark.compiled   # reaches a C kernel: run under the sanitizers too

M_P, L_P, MU, G = 1.0, 1.0, 1.0, 9.81  # pendulum: q = 0 hanging down


def pendulum_qddot(q, v, u):
    """Analytic pendulum acceleration (rad/s^2)."""
    return (u - MU * v - M_P * G * L_P * np.sin(q)) / (M_P * L_P**2)


def pendulum_data(n: int, seed: int, shrink: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Inputs ``(n, 3) = (q, qdot, u)`` on (``shrink`` times) the training region and targets ``(n, 1)``."""
    rng = np.random.default_rng(seed)
    X = shrink * rng.uniform([-1.5, -3.0, -10.0], [1.5, 3.0, 10.0], size=(n, 3))
    return X, pendulum_qddot(X[:, 0], X[:, 1], X[:, 2])[:, None]


def toy_data(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Two-joint toy: inputs ``(n, 6) = (q, qdot, u)``, smooth targets ``(n, 2)`` with different scales."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, 6)) * [1.0, 0.5, 2.0, 1.0, 5.0, 3.0] + [0.3, 0.0, 0.0, 0.0, 1.0, 0.0]
    Y = np.stack([np.sin(X[:, 0]) * X[:, 2] + 0.3 * X[:, 4], 40.0 * np.cos(X[:, 1] + 0.2 * X[:, 3]) - 5.0 * X[:, 5]], 1)
    return X, Y


def toy_model(n: int = 50, seed: int = 0) -> GPModel:
    """Toy GP with hand-set (scaled) hyperparameters, no fit."""
    X, Y = toy_data(n, seed)
    ell = np.array([[1.2, 1.5, 2.0, 3.0, 1.8, 2.5], [2.2, 0.9, 1.3, 1.1, 2.0, 1.6]])
    return GPModel(X, Y, ell, sf2=np.array([1.5, 0.8]), sn2=np.array([1e-4, 3e-4]))


@pytest.fixture(scope="module")
def fitted_toy():
    X, Y = toy_data(40, 1)
    return fit_gp(X, Y, restarts=0, seed=0)


@pytest.fixture(scope="module")
def fitted_pendulum():
    X, Y = pendulum_data(120, 2)
    return fit_gp(X, Y, restarts=0, seed=0)


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def central_differences(model, Xq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mean's and the latent variance's input gradients ``(M, D, d)`` at ``Xq (M, d)`` by central
    differences of ``model.predict`` (step ``1e-5`` of each input's scale)."""
    M, D, d = len(Xq), model.D, model.d
    fd_m, fd_v = np.empty((M, D, d)), np.empty((M, D, d))
    for c in range(d):
        h = 1e-5 * model.x_std[c]
        E = np.zeros_like(Xq)
        E[:, c] = h
        (mp, vp), (mm, vm) = model.predict(Xq + E), model.predict(Xq - E)
        fd_m[:, :, c], fd_v[:, :, c] = (mp - mm) / (2 * h), (vp - vm) / (2 * h)
    return fd_m, fd_v


# -- agreement with scikit-learn -----------------------------------------------------------
@pytest.mark.numerics
def test_predictions_equal_sklearn(fitted_toy):
    model, info = fitted_toy
    Xq, _ = toy_data(30, 7)
    mean, var_noisy = model.predict(Xq, noisy=True)
    _, var = model.predict(Xq)
    Zq = model.scale_x(Xq)
    for j in range(model.D):
        kernel = (ConstantKernel(model.sf2[j], "fixed") * RBF(model.ell[j], "fixed")
                  + WhiteKernel(model.sn2[j], "fixed"))
        sk = GaussianProcessRegressor(kernel, alpha=0.0, optimizer=None, normalize_y=False).fit(model.Z, model.y[:, j])
        m_sk, s_sk = sk.predict(Zq, return_std=True)  # std of a new observation: includes the white noise
        scale = model.y_std[j]
        assert np.max(np.abs(mean[:, j] - (model.y_mean[j] + scale * m_sk))) < 1e-8 * scale
        assert np.max(np.abs(np.sqrt(var_noisy[:, j]) - scale * s_sk)) < 1e-8 * scale
        assert np.allclose(var_noisy[:, j] - var[:, j], model.sn2[j] * scale**2, rtol=1e-9)
        assert abs(model.log_marginal_likelihood()[j] - sk.log_marginal_likelihood_value_) < 1e-8 * abs(
            sk.log_marginal_likelihood_value_)


# -- the likelihood and its optimizer ---------------------------------------------------------
def _sklearn_on(Z: np.ndarray, y: np.ndarray) -> GaussianProcessRegressor:
    from raico.stages.fit.gp_fit import make_kernel

    sk = GaussianProcessRegressor(make_kernel(Z.shape[1]), alpha=0.0, optimizer=None, normalize_y=False)
    return sk.fit(Z, y)


@pytest.mark.numerics
@pytest.mark.parametrize("theta, tol", [([0.3, 0.1, -0.4, 0.8, -2.0], REL),
                                        # near the bounds, cond(K) ~ 1e10: agreement to rounding of that
                                        ([5.0, 3.0, 4.0, 2.0, np.log(1e-6)], 1e-7)])
def test_lml_and_gradient_equal_sklearn_and_central_differences(theta, tol):
    from raico.stages.fit.gp_fit import lml_and_gradient

    X, Y = pendulum_data(80, 4)
    Z = (X - X.mean(0)) / X.std(0)
    y = (Y[:, 0] - Y[:, 0].mean()) / Y[:, 0].std()
    theta = np.asarray(theta, float)
    lml, g = lml_and_gradient(theta, Z, y)
    lml_sk, g_sk = _sklearn_on(Z, y).log_marginal_likelihood(theta, eval_gradient=True)
    assert abs(lml - lml_sk) <= tol * max(1.0, abs(lml_sk))
    assert _rel(g, g_sk) < 100 * tol
    if tol > REL:
        return  # rounding of an ill-conditioned K swamps central differences there
    h = 1e-6
    fd = np.array([(lml_and_gradient(theta + h * e, Z, y)[0] - lml_and_gradient(theta - h * e, Z, y)[0]) / (2 * h)
                   for e in np.eye(theta.size)])
    assert _rel(g, fd) < 1e-5


@pytest.mark.numerics
def test_fit_reaches_a_stationary_point_at_least_as_good_as_sklearn():
    """The own L-BFGS-B fit ends where the gradient vanishes (or a parameter is at a bound), with a
    likelihood at least sklearn's own optimizer's from the same start (to 1e-6 relative)."""
    from raico.stages.fit.gp_fit import initial_theta, lml_and_gradient, log_bounds, make_kernel

    X, Y = toy_data(60, 3)
    model, info = fit_gp(X, Y, restarts=0, seed=0)
    for j in range(model.D):
        theta = np.log(np.concatenate([[model.sf2[j]], model.ell[j], [model.sn2[j]]]))
        lml, g = lml_and_gradient(theta, model.Z, model.y[:, j])
        assert lml == pytest.approx(info["log_marginal_likelihood"][j], rel=1e-8)  # two factorizations
        b = log_bounds(model.d)
        free = ~(np.isclose(theta, b[:, 0]) | np.isclose(theta, b[:, 1]))
        assert np.max(np.abs(g[free])) < 1e-2 * max(1.0, abs(lml))
        sk = GaussianProcessRegressor(make_kernel(model.d), alpha=0.0, normalize_y=False, n_restarts_optimizer=0)
        sk.kernel.theta = initial_theta(model.d)
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sk.fit(model.Z, model.y[:, j])
        assert lml >= sk.log_marginal_likelihood_value_ - 1e-6 * abs(sk.log_marginal_likelihood_value_)


@pytest.mark.numerics
def test_warm_start_starts_at_the_given_model():
    """Started at an optimum, the fit stays there (log hyperparameters to 1e-3: a warm refit stops at a
    relative likelihood change of WARM_FTOL, the likelihood to 1e-7) and says it was warm."""
    X, Y = pendulum_data(100, 5)
    first, _ = fit_gp(X, Y, restarts=0, seed=0)
    again, info = fit_gp(X, Y, restarts=0, seed=0, start=first)
    assert info["warm_start"]
    assert np.allclose(np.log(again.ell), np.log(first.ell), atol=1e-3)
    assert np.allclose(np.log(again.sf2), np.log(first.sf2), atol=1e-3)
    l1, l2 = first.log_marginal_likelihood(), again.log_marginal_likelihood()
    assert np.all(np.abs(l2 - l1) <= 1e-7 * np.abs(l1) + 1e-6)
    with pytest.raises(ValueError, match="start model has"):
        fit_gp(X[:, :2], Y, start=first)


@pytest.mark.numerics
def test_noise_floor_respected_on_noise_free_data(fitted_pendulum):
    model, info = fitted_pendulum
    assert np.all(np.asarray(info["sn2"]) >= NOISE_FLOOR * (1 - REL))
    assert np.all(model.sn2 >= NOISE_FLOOR)
    assert np.all(model.sn2 < 1e-2)  # noise-free data: the fitted noise sits near the floor


# -- gradients ------------------------------------------------------------------------------
@pytest.mark.numerics
def test_gradients_match_central_differences():
    model = toy_model()
    Xq, _ = toy_data(6, 3)
    mean, var, dmean, dvar = model.predict_with_gradients(Xq)
    m0, v0 = model.predict(Xq)
    assert np.allclose(mean, m0, rtol=1e-9) and np.allclose(var, v0, rtol=1e-9)
    assert np.all(var > 0)
    m1, dm1 = model.mean_with_gradients(Xq)
    assert np.array_equal(dm1, dmean) and np.allclose(m1, mean, rtol=1e-9)
    fd_m, fd_v = central_differences(model, Xq)
    for j in range(model.D):
        assert _rel(dmean[:, j], fd_m[:, j]) < 1e-6
        assert _rel(dvar[:, j], fd_v[:, j]) < 1e-6
    assert np.max(np.abs(dvar)) > 0


def _direct_posterior(X, Y, model, Xq):
    """Reference posterior with gradients from ``numpy.linalg.solve`` on ``K + sn2 I`` and the exact
    (``cdist``) kernel, built from the physical data ``X, Y`` with ``model``'s hyperparameters and scaling:
    ``mean, var, dmean, dvar`` in physical units (shapes as ``GPModel.predict_with_gradients``)."""
    Z, Zq = model.scale_x(X), model.scale_x(Xq)
    y = (Y - model.y_mean) / model.y_std
    out = [np.empty((len(Xq), model.D)), np.empty((len(Xq), model.D)),
           np.empty((len(Xq), model.D, model.d)), np.empty((len(Xq), model.D, model.d))]
    for j in range(model.D):
        ell, sf2 = model.ell[j], model.sf2[j]
        K = sf2 * np.exp(-0.5 * (((Z[:, None, :] - Z[None, :, :]) / ell) ** 2).sum(-1)) + model.sn2[j] * np.eye(len(Z))
        Ks = sf2 * np.exp(-0.5 * (((Zq[:, None, :] - Z[None, :, :]) / ell) ** 2).sum(-1))  # (M, N)
        dKs = Ks[:, :, None] * (Z[None, :, :] - Zq[:, None, :]) / ell**2  # (M, N, d): dk*/dz*
        alpha = np.linalg.solve(K, y[:, j])
        B = np.linalg.solve(K, Ks.T)  # (N, M) = K^-1 k*
        out[0][:, j] = Ks @ alpha
        out[1][:, j] = sf2 - np.einsum("mn,nm->m", Ks, B)
        out[2][:, j] = np.einsum("mnc,n->mc", dKs, alpha)
        out[3][:, j] = -2.0 * np.einsum("mnc,nm->mc", dKs, B)
    scale = model.y_std[:, None] / model.x_std[None, :]
    return (out[0] * model.y_std + model.y_mean, out[1] * model.y_std**2,
            out[2] * scale, out[3] * scale * model.y_std[:, None])


def _assert_posterior_close(got, ref, model, tol):
    """Each of ``mean, var, dmean, dvar`` within ``tol`` of the reference, relative to its per-output
    scale (the variance relative to the prior variance ``sf2 y_std^2``, plus ``tol`` relative near the data)."""
    mean, var, dmean, dvar = got
    rm, rv, rdm, rdv = ref
    for j in range(model.D):
        assert np.max(np.abs(mean[:, j] - rm[:, j])) < tol * np.max(np.abs(rm[:, j] - model.y_mean[j]))
        assert np.max(np.abs(var[:, j] - rv[:, j])) < tol * model.sf2[j] * model.y_std[j] ** 2
        assert np.all(np.abs(var[:, j] - rv[:, j]) <= 1e3 * tol * rv[:, j])  # relative, also where var is small
        assert _rel(dmean[:, j], rdm[:, j]) < tol and _rel(dvar[:, j], rdv[:, j]) < tol
    assert np.all(var >= 0)


@pytest.mark.numerics
def test_posterior_equals_direct_solve_reference_also_after_update():
    """The BLAS-level posterior (in-place triangular solves, augmented-matmul kernel) equals a plain
    ``numpy.linalg.solve`` posterior to 1e-9 relative; after ``update`` it equals the reference on
    all the data (anything cached from before the update, e.g. an inverse, would fail here)."""
    X, Y = toy_data(90, 12)
    base = toy_model()
    model = GPModel(X[:60], Y[:60], base.ell, base.sf2, base.sn2)
    Xq = np.vstack([toy_data(30, 13)[0], X[:10] + 1e-3 * model.x_std])  # generic queries and near the data
    tol = 1e-9
    got = model.predict_with_gradients(Xq)
    _assert_posterior_close(got, _direct_posterior(X[:60], Y[:60], model, Xq), model, tol)
    model.update(X[60:], Y[60:])
    got = model.predict_with_gradients(Xq)
    ref = _direct_posterior(X, Y, model, Xq)
    _assert_posterior_close(got, ref, model, tol)
    m, v = model.predict(Xq)
    m1, dm1 = model.mean_with_gradients(Xq)
    assert np.array_equal(m, got[0]) and np.array_equal(v, got[1])  # the same computation in every entry point
    assert np.array_equal(m1, got[0]) and np.array_equal(dm1, got[2])
    assert np.array_equal(model.predict_mean(Xq), got[0])
    far = model.predict_with_gradients(model.x_mean + 50.0 * model.x_std * np.ones((1, model.d)))
    assert np.allclose(far[1][0], model.sf2 * model.y_std**2, rtol=1e-9)  # far from the data: the prior
    assert np.allclose(far[0][0], model.y_mean, rtol=0, atol=1e-9 * np.abs(model.Y).max())


@pytest.mark.numerics
def test_variance_accurate_on_an_ill_conditioned_kernel_matrix():
    """Noise at the floor, sf2 at its bound, long length-scales: cond(K + sn2 I) ~ 1e11, as on fitted
    models. The variance and its gradient agree with the triangular-solve reference (``scipy``
    ``solve_triangular`` on the Cholesky factor of the exact kernel matrix, variance as a sum of
    squares) to the rounding bound of that sum (5e-13 of the prior variance); an explicit ``(K + sn2 I)^-1`` misses by ~1e-6 here."""
    X, Y = pendulum_data(150, 31)
    model = GPModel(X, Y, np.full(3, 2.0), sf2=1e3, sn2=NOISE_FLOOR)
    assert np.linalg.cond(model.kernel_matrix(0)) > 1e10
    rng = np.random.default_rng(2)
    Xq = np.vstack([X[:40] + 1e-2 * model.x_std * rng.standard_normal((40, 3)), pendulum_data(40, 32)[0]])
    _, var, _, dvar = model.predict_with_gradients(Xq)
    Z, Zq, ell, sf2, s2 = model.Z, model.scale_x(Xq), model.ell[0], model.sf2[0], model.y_std[0] ** 2
    Ks = sf2 * np.exp(-0.5 * (((Zq[:, None, :] - Z[None, :, :]) / ell) ** 2).sum(-1))
    L = np.linalg.cholesky(model.kernel_matrix(0))
    V = solve_triangular(L, Ks.T, lower=True)
    B = solve_triangular(L, V, lower=True, trans="T")
    W = Ks * B.T
    v_ref = (sf2 - (V * V).sum(0)) * s2
    dv_ref = -2.0 * (W @ Z - Zq * W.sum(1)[:, None]) / ell**2 * s2 / model.x_std
    # both: sf2 minus a sum of N squares of a forward substitution's entries (N terms each): 2N roundings
    # on sf2's scale (a triangular solve's error does not grow with cond(L) ~ 3e5 here; measured <= 230 eps)
    assert np.max(np.abs(var[:, 0] - v_ref)) < bound(2 * len(Z)) * sf2 * s2
    assert np.all(var >= 0) and np.min(v_ref) < 1e-8 * sf2 * s2  # some queries sit where var is ~1e-9 sf2
    assert _rel(dvar[:, 0], dv_ref) < 1e-6


# -- incremental update ---------------------------------------------------------------------
@pytest.mark.numerics
def test_incremental_update_equals_refit():
    X, Y = toy_data(80, 5)
    base = toy_model()
    model = GPModel(X[:50], Y[:50], base.ell, base.sf2, base.sn2)
    L_old = model.L.copy()
    model.update(X[50:], Y[50:])
    assert np.array_equal(model.L[:, :50, :50], L_old)  # the old block is extended, not refactorized
    ref = refit_fixed(model, X, Y)
    assert model.N == ref.N == 80
    Xq, _ = toy_data(25, 9)
    (m1, v1), (m2, v2) = model.predict(Xq), ref.predict(Xq)
    for j in range(model.D):
        assert _rel(m1[:, j], m2[:, j]) < 1e-8
        assert _rel(v1[:, j], v2[:, j]) < 1e-8
        assert _rel(model.L[j], ref.L[j]) < 1e-8
    assert np.allclose(model.log_marginal_likelihood(), ref.log_marginal_likelihood(), rtol=1e-9)
    with pytest.raises(ValueError, match="^training data must be finite$"):
        model.update(X[:2], np.full((2, 2), np.nan))
    with pytest.raises(ValueError, match=r"^update expects X_new \(n, 6\) and Y_new \(n, 2\), got \(2, 6\), \(2, 1\)$"):
        model.update(X[:2], Y[:2, :1])
    assert model.N == 80  # a refused update leaves the model as it was


# -- learned dynamics -----------------------------------------------------------------------
@pytest.mark.numerics
def test_learned_linearization_exact_and_batched():
    dyn = LearnedDynamics(toy_model(), n_q=2, dt=0.01)
    assert isinstance(dyn, Dynamics) and (dyn.n_x, dyn.n_u) == (4, 2)
    rng = np.random.default_rng(4)
    X = rng.normal(size=(5, 4)) * 0.7
    U = rng.normal(size=(5, 2)) * 2.0
    A, a, B = dyn.linearize_trajectory(X, U)
    for t in range(5):
        At, at, Bt = dyn.linearize(X[t], U[t])
        assert close(At, A[t], scale=1.0) and close(Bt, B[t], scale=1.0)
        assert close(at, a[t], scale=1 + scale_of(X[t], U[t]))
        x1 = dyn.step(X[t], U[t])
        assert close(A[t] @ X[t] + a[t] + B[t] @ U[t], x1, scale=scale_of(X[t], U[t]))
        fdA = np.stack([(dyn.step(X[t] + e, U[t]) - dyn.step(X[t] - e, U[t])) / 2e-6 for e in 1e-6 * np.eye(4)], 1)
        fdB = np.stack([(dyn.step(X[t], U[t] + e) - dyn.step(X[t], U[t] - e)) / 2e-6 for e in 1e-6 * np.eye(2)], 1)
        assert _rel(A[t], fdA) < 1e-6 and _rel(B[t], fdB) < 1e-6
        assert np.max(np.abs(B[t])) > 1e-6
    assert np.allclose(dyn.step_batch(X, U), np.stack([dyn.step(x, u) for x, u in zip(X, U)]), rtol=1e-9)
    var, dvx, dvu = dyn.predict_variance(X, U)
    _, v_ref, _, dv_ref = dyn.model.predict_with_gradients(np.hstack([X, U]))
    assert var.shape == (5, 2) and np.array_equal(var, v_ref)
    assert np.array_equal(dvx, dv_ref[:, :, :4]) and np.array_equal(dvu, dv_ref[:, :, 4:])


@pytest.mark.numerics
def test_point_mean_and_gradient_equal_the_batched_path_also_after_update(monkeypatch):
    """The compiled one-point path (what the sweeps' relinearizations call) against
    ``mean_with_gradients``; after ``update()`` a cached copy of the old training set would fail."""
    import raico.plants.gp as gp

    model = toy_model()
    rng = np.random.default_rng(7)
    Q = rng.normal(size=(6, model.d))
    for step in range(2):
        m_ref, g_ref = model.mean_with_gradients(Q)
        for x, mr, gr in zip(Q, m_ref, g_ref):
            m, g = model.point_mean_with_gradients(x)
            assert close(m, mr, scale=scale_of(m_ref))
            assert close(g, gr, scale=scale_of(g_ref))
        if step == 0:
            Xn = rng.normal(size=(5, model.d))
            model.update(Xn, np.sin(Xn[:, :model.D]))
    m, g = model.point_mean_with_gradients(np.full(model.d, np.nan))
    assert np.all(np.isnan(m)) and np.all(np.isnan(g))
    monkeypatch.setattr(gp._point_lib, "_lib", None)
    monkeypatch.setattr(gp._point_lib, "_loaded", True)          # no compiler: the numpy path, same numbers
    m2, g2 = model.point_mean_with_gradients(Q[0])
    m_ref, g_ref = model.mean_with_gradients(Q[:1])
    assert np.array_equal(m2, m_ref[0]) and np.array_equal(g2, g_ref[0])


@pytest.mark.numerics
def test_point_variance_equals_the_batched_path_also_after_update(monkeypatch):
    """The compiled one-point mean, variance and gradients (the uncertainty term's relinearization
    in the sweeps) against ``predict_with_gradients``, also after ``update()`` (a cached copy of the
    old factor would fail), NaN for a non-finite query, and the numpy path without a compiler."""
    import raico.plants.gp as gp

    model = toy_model(n=80)
    rng = np.random.default_rng(3)
    Q = np.vstack([rng.normal(size=(5, model.d)), model.X[:2]])   # far from and on the data
    for step in range(2):
        ref = model.predict_with_gradients(Q)
        for i, x in enumerate(Q):
            for got, r in zip(model.point_predict_with_gradients(x), ref):
                assert np.allclose(got, r[i], rtol=1e-9, atol=1e-9 * np.abs(r).max())
        if step == 0:
            Xn = rng.normal(size=(5, model.d))
            model.update(Xn, np.sin(Xn[:, :model.D]))
    assert all(np.all(np.isnan(a)) for a in model.point_predict_with_gradients(np.full(model.d, np.nan)))
    monkeypatch.setattr(gp._point_lib, "_lib", None)
    monkeypatch.setattr(gp._point_lib, "_loaded", True)
    ref = model.predict_with_gradients(Q[:1])
    for got, r in zip(model.point_predict_with_gradients(Q[0]), ref):
        assert np.array_equal(got, r[0])


@pytest.mark.numerics
def test_learned_controller_rollout_compiled_equals_python_steps(monkeypatch):
    """``LearnedDynamics.controller_rollout`` (one compiled call) against stepping ``step`` in
    Python (raico.planning.problem.controller_rollout), also on the sparse GP, NaN propagated."""
    import raico.plants.gp as gp
    from raico.planning.problem import controller_rollout
    from raico.stages.fit.gp_fit import fit_sparse_gp

    rng = np.random.default_rng(5)
    X, Y = toy_data(120, 4)
    sparse, _ = fit_sparse_gp(X, Y, inducing=30, restarts=0)
    T = 60
    o, O = 0.3 * rng.normal(size=(T, 2)), 0.05 * rng.normal(size=(T, 2, 4))
    for model in (toy_model(), sparse):
        dyn = LearnedDynamics(model, n_q=2, dt=0.01)
        x0 = np.array([0.2, -0.1, 0.3, 0.0])
        Xc, Uc = dyn.controller_rollout(x0, o, O)
        Xp, Up = controller_rollout(dyn, x0, o, O)
        assert close(Xc, Xp, scale=1.0) and close(Uc, Up, scale=1.0)
        o_bad = o.copy()
        o_bad[30, 0] = np.nan
        Xn, _ = dyn.controller_rollout(x0, o_bad, O)
        assert np.all(np.isfinite(Xn[:31])) and np.all(np.isnan(Xn[31:, 2:]))
        monkeypatch.setattr(gp._point_lib, "_lib", None)
        monkeypatch.setattr(gp._point_lib, "_loaded", True)      # no compiler: the Python steps
        Xf, _ = dyn.controller_rollout(x0, o, O)
        assert np.array_equal(Xf, controller_rollout(dyn, x0, o, O)[0]) and close(Xf, Xp, scale=1.0)
        monkeypatch.undo()


def test_learned_nonfinite_inputs_give_nan():
    dyn = LearnedDynamics(toy_model(), n_q=2, dt=0.01)
    x = np.array([0.1, np.nan, 0.0, 0.2])
    assert np.all(np.isnan(dyn.step(x, np.zeros(2))))
    A, a, B = dyn.linearize_trajectory(np.vstack([x, np.zeros(4)]), np.array([[0.0, np.inf], [0.0, 0.0]]))
    assert np.all(np.isnan(A[0])) and np.all(np.isnan(a[0])) and np.all(np.isnan(B[0]))
    assert np.all(np.isfinite(A[1])) and np.all(np.isfinite(a[1]))
    var, dvx, _ = dyn.predict_variance(x[None, :], np.zeros((1, 2)))
    assert np.all(np.isnan(var)) and np.all(np.isnan(dvx))


@pytest.mark.numerics
def test_learned_pendulum_predicts_true_acceleration(fitted_pendulum):
    model, _ = fitted_pendulum
    dyn = build_learned(SimpleNamespace(n_q=1), 0.002, model.to_arrays())
    Xt, Yt = pendulum_data(200, 11, shrink=0.9)  # inside the training region
    qdd = np.array([dyn.qddot(x[:1], x[1:2], x[2:]) for x in Xt])
    nrmse = np.sqrt(np.mean((qdd - Yt) ** 2)) / Yt.std()
    assert nrmse < 1e-3, nrmse
    x, u = np.array([0.4, -1.0]), np.array([2.0])
    A, a, B = dyn.linearize(x, u)
    dt, c = 0.002, np.cos(0.4)
    A_true = np.array([[1 - dt * dt * G * c, dt * (1 - dt * MU)], [-dt * G * c, 1 - dt * MU]])
    assert np.allclose(A, A_true, atol=2e-3 * dt) and np.allclose(B[:, 0], [dt * dt, dt], rtol=1e-2)


# -- storage ----------------------------------------------------------------------------------
@pytest.mark.numerics
def test_to_from_arrays_round_trip(tmp_path):
    model = toy_model()
    model.update(*toy_data(10, 8))
    np.savez(tmp_path / "gp.npz", **model.to_arrays())
    with np.load(tmp_path / "gp.npz", allow_pickle=False) as f:
        loaded = GPModel.from_arrays(dict(f))
    Xq, _ = toy_data(20, 6)
    for a, b in zip(model.predict_with_gradients(Xq), loaded.predict_with_gradients(Xq)):
        assert np.array_equal(a, b)
    compact = GPModel.from_arrays(model.to_arrays(include_factor=False))  # refactorized
    assert _rel(compact.predict(Xq)[0], model.predict(Xq)[0]) < 1e-8


# -- bounded cost -------------------------------------------------------------------------------
@pytest.mark.numerics
def test_subsampling_cap_and_its_measured_cost():
    X, Y = pendulum_data(260, 21)
    idx = subsample_indices(X, 80)
    assert len(idx) == 80 and np.all(np.diff(idx) > 0)
    assert set(range(220, 260)) <= set(idx.tolist())  # the most recent half of the cap
    assert np.array_equal(idx, subsample_indices(X, 80))  # deterministic
    Xt, Yt = pendulum_data(100, 22, shrink=0.9)
    cost = measure_cap_cost(X, Y, Xt, Yt, max_points=80)
    assert cost["n_capped"] == 80 and cost["n_full"] == 260
    model, info = fit_gp(X, Y, restarts=0, seed=0, max_points=80)  # the capped model, fit again
    assert model.N == info["n_points"] == 80 and info["n_input"] == 260
    assert close(model.Z, model.scale_x(X[idx]), scale=1.0)  # trained on the subsample
    # the reported errors, recomputed from the two models' predictions on the test set
    full = refit_fixed(model, X, Y)
    rmse_capped = np.sqrt(np.mean((model.predict(Xt)[0] - Yt) ** 2, axis=0))
    rmse_full = np.sqrt(np.mean((full.predict(Xt)[0] - Yt) ** 2, axis=0))
    np.testing.assert_allclose(cost["rmse_capped"], rmse_capped, rtol=1e-9)
    np.testing.assert_allclose(cost["rmse_full"], rmse_full, rtol=1e-9)
    np.testing.assert_allclose(cost["nrmse_capped"], rmse_capped / Yt.std(0), rtol=1e-9)
    np.testing.assert_allclose(cost["rmse_ratio"], rmse_capped / rmse_full, rtol=1e-9)
    assert cost["nrmse_capped"][0] < 0.02 and cost["rmse_full"][0] <= 1.5 * cost["rmse_capped"][0]


@pytest.mark.numerics
def test_uncertainty_term_units_raw_is_the_predictive_variance():
    """Thesis eq. 4.3: g = var(x*) in (rad/s^2)^2 ('raw'); 'standardized' divides by the training
    outputs' variance. At sigma* = 0 the raw cost is the standardized one times y_std^4 per output."""
    from raico.planning.costs import Uncertainty
    from raico.planning.costs import uncertainty_example as example
    from raico.plants.robots import shared_robot

    robot = shared_robot("arm5")
    raw, std = example(robot, robot.default_q, "raw"), example(robot, robot.default_q, "standardized")
    rng = np.random.default_rng(0)
    X = robot.default_q[None, :] + 0.1 * rng.standard_normal((4, robot.n_q))
    X = np.hstack([X, 0.1 * rng.standard_normal((4, robot.n_q))])
    U = 0.1 * rng.standard_normal((4, robot.n_q))
    g_raw, Jx_raw, _ = raw.variance(X, U)
    g_std, Jx_std, _ = std.variance(X, U)
    y_std = np.asarray(raw.model.model.y_std)
    assert np.allclose(g_raw, g_std * y_std**2) and np.allclose(Jx_raw, Jx_std * (y_std**2)[:, None])
    var, _, _ = raw.model.predict_variance(X, U)
    assert np.array_equal(g_raw, var)
    zero_raw = Uncertainty(raw.model, 0.0, 1.0, T=4, units="raw").joint_value(X, U)
    zero_std = Uncertainty(raw.model, 0.0, 1.0, T=4, units="standardized").joint_value(X, U)
    assert np.allclose(zero_raw, ((g_std * y_std**2) ** 2).sum(axis=1)) and not np.allclose(zero_raw, zero_std)
    with pytest.raises(ValueError, match="units"):
        Uncertainty(raw.model, 0.0, 1.0, T=4, units="furlongs")


@pytest.mark.numerics
def test_hyperparameter_fits_identical_on_one_or_two_threads(monkeypatch):
    """The outputs' fits run on ``RAICO_THREADS`` threads (raico.plants.threads.map_outputs): the same
    hyperparameters bit for bit on 1 and 2; a bad value is one clear error."""
    from raico.plants import threads

    X, Y = toy_data(80, 2)
    fits = []
    for n in ("1", "2"):
        monkeypatch.setenv("RAICO_THREADS", n)
        assert threads.output_threads() == int(n)
        model, _ = fit_gp(X, Y, restarts=1, seed=0)
        fits.append(np.concatenate([model.ell.ravel(), model.sf2, model.sn2]))
    assert np.array_equal(fits[0], fits[1])
    assert threads.map_outputs(lambda j: j * j, 5) == [0, 1, 4, 9, 16]
    monkeypatch.setenv("RAICO_THREADS", "two")
    with pytest.raises(ValueError, match="RAICO_THREADS must be a positive integer"):
        threads.output_threads()


@pytest.mark.numerics
def test_learned_compiled_linearizer_equals_linearize():
    """The sweep kernel's compiled relinearization of the learned dynamics (``c_linearizer``) against
    ``linearize``: A and B bit for bit, the affine term to rounding (the products A x, B u); NaN and an
    error code for a non-finite state."""
    import ctypes

    fn, ctx, keep = LearnedDynamics(toy_model(), n_q=2, dt=0.01).c_linearizer()
    dyn = LearnedDynamics(toy_model(), n_q=2, dt=0.01)
    call = ctypes.CFUNCTYPE(ctypes.c_int, *[ctypes.c_void_p] * 6)(fn)
    rng = np.random.default_rng(2)
    for _ in range(5):
        x, u = rng.normal(size=4), rng.normal(size=2)
        A, a, B = np.empty((4, 4)), np.empty(4), np.empty((4, 2))
        assert call(ctx, x.ctypes.data, u.ctypes.data, A.ctypes.data, a.ctypes.data, B.ctypes.data) == 0
        A2, a2, B2 = dyn.linearize(x, u)
        assert np.array_equal(A, A2) and np.array_equal(B, B2) and close(a, a2, scale=1 + scale_of(x, u))
    x[1] = np.nan
    assert call(ctx, x.ctypes.data, u.ctypes.data, A.ctypes.data, a.ctypes.data, B.ctypes.data) == -1
    assert np.all(np.isnan(A)) and np.all(np.isnan(a)) and np.all(np.isnan(B))
