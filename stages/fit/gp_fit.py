"""GP hyperparameter fitting (SPEC §7, thesis §4.2): scikit-learn's optimizer, posterior in ``plants.gp``.

Per output dimension, the log marginal likelihood of
``ConstantKernel * RBF(length_scale=ones(d)) + WhiteKernel`` is maximized by sklearn's
``GaussianProcessRegressor`` (L-BFGS-B, ``n_restarts_optimizer`` random restarts drawn from the
bounds with ``random_state=seed``) on the standardized data of ``plants.gp`` (inputs per
dimension, outputs per output), with ``alpha=0`` and the noise bounded below by
``noise_floor`` (so sklearn's likelihood and ``GPModel``'s posterior use the same
``K + sn2 I``, nothing else on the diagonal). Bounds (standardized units): length-scales
``[1e-2, 1e3]``, ``sf2`` in ``[1e-3, 1e3]``, ``sn2`` in ``[noise_floor, 1]``; ``sf2 <= 1e3`` and
``sn2 >= 1e-6`` keep ``cond(K + sn2 I) <= 1 + 1e9 N`` (nearly linear dependencies, e.g. the
pendulum's on ``qdot`` and ``u``, push ``sf2`` and the length-scales to their upper bounds; the
fit then records sklearn's bound warnings in ``info["warnings"]``). The fitted parameters build a
``GPModel``.

Bounded cost (``max_points``): when a training set exceeds the cap, ``subsample_indices`` keeps

1. the most recent ``ceil(recent_fraction * max_points)`` rows (rows are in collection order,
   so these are the data around the trajectory the planner works on now), then
2. greedy farthest-point selection among the older rows in standardized input space: each step
   adds the older row farthest (Euclidean) from everything kept so far (ties: lowest index),

which is deterministic and covers the older (babbling) region evenly. ``measure_cap_cost``
reports what the cap costs in held-out RMSE.
"""

from __future__ import annotations

import math
import time
import warnings

import numpy as np
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

from plants.gp import NOISE_FLOOR, GPModel, column_std

LENGTH_SCALE_BOUNDS = (1e-2, 1e3)  # standardized input units
SIGNAL_BOUNDS = (1e-3, 1e3)  # sf2, standardized output units
NOISE_MAX = 1.0  # upper bound of sn2, standardized output units


def make_kernel(d: int, noise_floor: float = NOISE_FLOOR):
    """sklearn kernel ``ConstantKernel * RBF(ones(d)) + WhiteKernel`` with this module's bounds."""
    return (ConstantKernel(1.0, SIGNAL_BOUNDS) * RBF(length_scale=np.ones(d), length_scale_bounds=LENGTH_SCALE_BOUNDS)
            + WhiteKernel(noise_level=max(1e-3, noise_floor), noise_level_bounds=(noise_floor, NOISE_MAX)))


def kernel_params(kernel) -> tuple[np.ndarray, float, float]:
    """``(length_scales (d,), sf2, sn2)`` of a fitted ``make_kernel`` kernel."""
    return (np.atleast_1d(np.asarray(kernel.k1.k2.length_scale, float)),
            float(kernel.k1.k1.constant_value), float(kernel.k2.noise_level))


def fit_gp(X: np.ndarray, Y: np.ndarray, *, restarts: int = 2, seed: int = 0,
           noise_floor: float = NOISE_FLOOR, max_points: int | None = None) -> tuple[GPModel, dict]:
    """Fit one GP per output of ``Y (N, D)`` on inputs ``X (N, d)`` (physical units) -> ``(GPModel, info)``.

    ``max_points`` caps the training set (``subsample_indices``). ``info``: ``fit_time_s`` (D,),
    ``log_marginal_likelihood`` (D,, scaled units), ``length_scales`` (D, d, standardized input
    units), ``sf2`` and ``sn2`` (D,, standardized output units), ``n_points``, ``n_input``,
    ``kept`` (indices into ``X``) and sklearn's warnings (e.g. a parameter at its bound)."""
    X, Y = _check_xy(X, Y)
    n_input = X.shape[0]
    kept = np.arange(n_input)
    if max_points is not None and n_input > max_points:
        kept = subsample_indices(X, max_points)
        X, Y = X[kept], Y[kept]
    x_mean, x_std, y_mean, y_std = X.mean(0), column_std(X), Y.mean(0), column_std(Y)
    Z, y = (X - x_mean) / x_std, (Y - y_mean) / y_std
    D, d = Y.shape[1], X.shape[1]
    ell, sf2, sn2, times, lml_sk, messages = np.empty((D, d)), np.empty(D), np.empty(D), [], [], []
    for j in range(D):
        gpr = GaussianProcessRegressor(kernel=make_kernel(d, noise_floor), alpha=0.0, normalize_y=False,
                                       n_restarts_optimizer=restarts, random_state=seed)
        t0 = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            gpr.fit(Z, y[:, j])
        times.append(time.perf_counter() - t0)
        messages += sorted({f"output {j}: {w.message}" for w in caught})
        ell[j], sf2[j], sn2[j] = kernel_params(gpr.kernel_)
        lml_sk.append(float(gpr.log_marginal_likelihood_value_))
    model = GPModel(X, Y, ell, sf2, sn2, x_mean=x_mean, x_std=x_std, y_mean=y_mean, y_std=y_std,
                    noise_floor=noise_floor)
    info = {"fit_time_s": times, "log_marginal_likelihood": model.log_marginal_likelihood().tolist(),
            "log_marginal_likelihood_sklearn": lml_sk, "length_scales": ell.tolist(), "sf2": sf2.tolist(),
            "sn2": sn2.tolist(), "n_points": int(X.shape[0]), "n_input": int(n_input),
            "kept": kept.tolist(), "warnings": messages}
    return model, info


def refit_fixed(model: GPModel, X: np.ndarray, Y: np.ndarray) -> GPModel:
    """A new ``GPModel`` on ``X (N, d)``, ``Y (N, D)`` with ``model``'s hyperparameters and scaling, factorized from scratch."""
    X, Y = _check_xy(X, Y)
    return GPModel(X, Y, model.ell, model.sf2, model.sn2, x_mean=model.x_mean, x_std=model.x_std,
                   y_mean=model.y_mean, y_std=model.y_std, noise_floor=model.noise_floor)


def subsample_indices(X: np.ndarray, max_points: int, *, recent_fraction: float = 0.5) -> np.ndarray:
    """Sorted indices ``(min(N, max_points),)`` of the rows of ``X (N, d)`` to keep (rule in the module docstring)."""
    N = X.shape[0]
    if max_points < 1:
        raise ValueError(f"max_points must be >= 1, got {max_points}")
    if N <= max_points:
        return np.arange(N)
    Z = (X - X.mean(0)) / column_std(X)
    n_recent = min(max_points, math.ceil(recent_fraction * max_points))
    n_old = N - n_recent
    Zold = Z[:n_old]
    chosen: list[int] = []
    dmin = np.full(n_old, np.inf)
    for s in range(0, n_recent, 256):  # distance of each older row to the kept recent rows
        R = Z[n_old + s:n_old + min(n_recent, s + 256)]
        sq = (Zold**2).sum(1)[:, None] + (R**2).sum(1)[None, :] - 2.0 * Zold @ R.T
        dmin = np.minimum(dmin, sq.min(1))
    if n_recent == 0:  # start from the most recent row
        chosen.append(n_old - 1)
        dmin = ((Zold - Zold[-1]) ** 2).sum(1)
        dmin[-1] = -1.0
    while len(chosen) < max_points - n_recent:
        i = int(np.argmax(dmin))
        chosen.append(i)
        dmin = np.minimum(dmin, ((Zold - Zold[i]) ** 2).sum(1))
        dmin[i] = -1.0
    return np.sort(np.concatenate([np.asarray(chosen, int), np.arange(n_old, N)]))


def rmse(model: GPModel, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Root mean squared error ``(D,)`` of the GP mean on ``X (M, d)`` against ``Y (M, D)`` (physical units)."""
    mean, _ = model.predict(X)
    return np.sqrt(np.mean((mean - Y) ** 2, axis=0))


def measure_cap_cost(X: np.ndarray, Y: np.ndarray, X_test: np.ndarray, Y_test: np.ndarray, *, max_points: int,
                     restarts: int = 0, seed: int = 0, noise_floor: float = NOISE_FLOOR,
                     refit_full: bool = False) -> dict:
    """What ``max_points`` costs: held-out RMSE of the capped GP against the GP on all ``N`` points.

    The capped model is ``fit_gp(..., max_points=max_points)``. The uncapped reference is the
    exact GP on all points at the capped model's hyperparameters (``refit_fixed``), or, with
    ``refit_full``, a separate ``fit_gp`` on all points. Returns per-output lists (physical
    units): ``rmse_capped``, ``rmse_full``, ``rmse_ratio`` (capped / full), ``nrmse_capped`` and
    ``nrmse_full`` (divided by the std of ``Y_test``), plus ``n_full``, ``n_capped``, the
    fit time and the prediction time (ms) of each model on ``X_test``."""
    X, Y = _check_xy(X, Y)
    t0 = time.perf_counter()
    capped, info = fit_gp(X, Y, restarts=restarts, seed=seed, noise_floor=noise_floor, max_points=max_points)
    t_capped = time.perf_counter() - t0
    t0 = time.perf_counter()
    if refit_full:
        full, _ = fit_gp(X, Y, restarts=restarts, seed=seed, noise_floor=noise_floor)
    else:
        full = refit_fixed(capped, X, Y)
    t_full = time.perf_counter() - t0
    out = {"n_full": full.N, "n_capped": capped.N, "max_points": int(max_points), "refit_full": bool(refit_full),
           "fit_s_capped": t_capped, "fit_s_full": t_full}
    scale = column_std(np.asarray(Y_test, float))
    for name, m in (("capped", capped), ("full", full)):
        t0 = time.perf_counter()
        e = rmse(m, X_test, Y_test)
        out[f"predict_ms_{name}"] = 1e3 * (time.perf_counter() - t0)
        out[f"rmse_{name}"] = e.tolist()
        out[f"nrmse_{name}"] = (e / scale).tolist()
    out["rmse_ratio"] = (np.asarray(out["rmse_capped"]) / np.maximum(out["rmse_full"], 1e-300)).tolist()
    return out


def _check_xy(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    X, Y = np.asarray(X, float), np.asarray(Y, float)
    if X.ndim != 2 or Y.ndim != 2 or X.shape[0] != Y.shape[0]:
        raise ValueError(f"expected X (N, d) and Y (N, D), got {X.shape} and {Y.shape}")
    if X.shape[0] == 0:
        raise ValueError("no training data")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
        raise ValueError("training data must be finite")
    return X, Y
