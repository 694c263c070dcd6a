"""GP hyperparameter fitting (thesis §4.2): type-II maximum likelihood, posterior in ``raico.plants.gp``.

Per output dimension, the log marginal likelihood of the kernel
``sf2 * exp(-|z - z'|^2_ell / 2) + sn2 * delta`` (scikit-learn's
``ConstantKernel * RBF(length_scale=ones(d)) + WhiteKernel``, :func:`make_kernel`) is maximized
over ``theta = log(sf2, ell_1..ell_d, sn2)`` (sklearn's order) by L-BFGS-B with the analytic
gradient (:func:`lml_and_gradient`, equal to sklearn's, tested) on the standardized data of
``raico.plants.gp``. Starts: the kernel's initial point (or ``start``, a previous model's
hyperparameters: the learning loop's warm start, which stops at ``WARM_FTOL``), then ``restarts``
random points drawn uniformly in the log bounds (``numpy.random.RandomState(seed)``); the best
likelihood wins. The outputs are fitted independently, on ``raico.plants.threads.output_threads()``
threads (the same numbers on any count). Bounds (standardized units): length-scales ``[1e-2, 1e3]``,
``sf2`` in ``[1e-3, 1e3]``, ``sn2`` in ``[noise_floor, 1]``; a parameter that ends at a bound is
named in ``info["warnings"]``. The fitted parameters build a ``GPModel``.

Bounded cost (``max_points``): above the cap ``subsample_indices`` keeps the most recent rows and
fills the rest by greedy farthest-point selection among the older ones (deterministic);
``measure_cap_cost`` reports what the cap costs in held-out RMSE. Sparse GP (``fit_sparse_gp``):
the hyperparameters of the exact likelihood on the ``M`` points ``subsample_indices`` keeps, the
posterior FITC on all (capped) points with ``M`` inducing inputs (``raico.plants.gp.select_inducing``).
The details: docs/learning.md, "Fitting the hyperparameters".
"""

from __future__ import annotations

import math
import time

import numpy as np
from scipy.linalg import lapack
from scipy.optimize import minimize

from raico.plants.gp import NOISE_FLOOR, AngleInputGP, GPBase, GPModel, SparseGPModel, column_std
from raico.plants.threads import map_outputs

LENGTH_SCALE_BOUNDS = (1e-2, 1e3)  # standardized input units
SIGNAL_BOUNDS = (1e-3, 1e3)  # sf2, standardized output units
NOISE_MAX = 1.0  # upper bound of sn2, standardized output units


def make_kernel(d: int, noise_floor: float = NOISE_FLOOR):
    """sklearn kernel ``ConstantKernel * RBF(ones(d)) + WhiteKernel`` with this module's bounds (the
    reference the own likelihood is tested against)."""
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    return (ConstantKernel(1.0, SIGNAL_BOUNDS) * RBF(length_scale=np.ones(d), length_scale_bounds=LENGTH_SCALE_BOUNDS)
            + WhiteKernel(noise_level=max(1e-3, noise_floor), noise_level_bounds=(noise_floor, NOISE_MAX)))


def log_bounds(d: int, noise_floor: float = NOISE_FLOOR) -> np.ndarray:
    """``(d + 2, 2)`` bounds of ``theta = log(sf2, ell_1..ell_d, sn2)``."""
    return np.log(np.array([SIGNAL_BOUNDS, *[LENGTH_SCALE_BOUNDS] * d, (noise_floor, NOISE_MAX)], float))


def initial_theta(d: int, noise_floor: float = NOISE_FLOOR) -> np.ndarray:
    """The kernel's initial point ``log(1, ones(d), max(1e-3, noise_floor))`` ``(d + 2,)``."""
    return np.log(np.array([1.0, *[1.0] * d, max(1e-3, noise_floor)]))


def lml_and_gradient(theta: np.ndarray, Z: np.ndarray, y: np.ndarray) -> tuple[float, np.ndarray]:
    """Log marginal likelihood of ``y (N,)`` at inputs ``Z (N, d)`` and its gradient ``(d + 2,)``
    with respect to ``theta = log(sf2, ell_1..ell_d, sn2)``; ``(-inf, 0)`` when ``K + sn2 I`` is not
    positive definite in floating point.

    ``dL/dtheta_k = tr(W dK/dtheta_k) / 2`` with ``W = a a^T - K^-1``, ``a = K^-1 y``:
    ``dK/dlog sf2 = K_se``, ``dK/dlog ell_i = K_se (z_i - z_i')^2 / ell_i^2``,
    ``dK/dlog sn2 = sn2 I``."""
    theta = np.asarray(theta, float)
    N, d = Z.shape
    sf2, ell, sn2 = math.exp(theta[0]), np.exp(theta[1:-1]), math.exp(theta[-1])
    Q = Z / ell
    qq = (Q * Q).sum(1)
    S = Q @ Q.T
    S *= 2.0
    S -= qq[:, None]
    S -= qq[None, :]
    np.minimum(S, 0.0, out=S)
    S *= 0.5
    Kse = np.exp(S, out=S)
    Kse *= sf2
    K = Kse.copy()
    K.flat[::N + 1] += sn2
    L, info = lapack.dpotrf(K, lower=1, clean=1, overwrite_a=1)
    if info != 0:
        return -math.inf, np.zeros_like(theta)
    a, _ = lapack.dpotrs(L, y, lower=1)
    lml = -0.5 * float(y @ a) - float(np.log(np.diagonal(L)).sum()) - 0.5 * N * math.log(2.0 * math.pi)
    # K^-1 from the factor (LAPACK dpotri: its lower triangle, the upper left zero: half the flops of
    # solving against the identity), used through M = K^-1 o K_se in its lower triangle (M_low):
    # W o K_se = diag(a) K_se diag(a) - M with M = M_low + M_low^T - diag(M) (symmetric), so the
    # sums and products below never form W or the full inverse.
    Kinv, info = lapack.dpotri(L, lower=1, overwrite_c=1)
    if info != 0:
        return -math.inf, np.zeros_like(theta)
    dg = np.diagonal(Kinv).copy()           # diag(K^-1)
    Kinv *= Kse                              # M_low (upper triangle stays 0)
    dM = np.diagonal(Kinv).copy()            # diag(M) = diag(K^-1) sf2 (K_se's diagonal)
    Ka = Kse @ a                             # K_se a
    rM = Kinv.sum(1) + Kinv.sum(0) - dM      # row sums of M
    r = a * Ka - rM                          # row sums of W o K_se
    grad = np.empty_like(theta)
    grad[-1] = 0.5 * sn2 * (float(a @ a) - float(dg.sum()))   # tr(W) = a.a - tr(K^-1)
    grad[0] = 0.5 * float(r.sum())
    # (W o K_se) Q = a o (K_se (a o Q)) - (M_low Q + M_low^T Q - dM o Q), per column
    WQ = a[:, None] * (Kse @ (a[:, None] * Q)) - (Kinv @ Q + Kinv.T @ Q - dM[:, None] * Q)
    grad[1:-1] = ((Q * Q) * r[:, None]).sum(0) - (Q * WQ).sum(0)
    return lml, grad


WARM_FTOL = 1e-7  # L-BFGS-B's stop on the likelihood's relative change for a warm-started refit (docs/learning.md)


def maximize_lml(Z: np.ndarray, y: np.ndarray, starts: list[np.ndarray], bounds: np.ndarray,
                 ftol: float | None = None) -> tuple[np.ndarray, float]:
    """L-BFGS-B (scipy, analytic gradient) from every start in ``starts``; the best ``(theta, lml)``.
    ``ftol``: the stop on the relative change of the likelihood (None: scipy's default, 2.2e-9)."""
    best, best_lml = None, -math.inf

    def objective(theta):
        lml, g = lml_and_gradient(theta, Z, y)
        if not math.isfinite(lml):
            return 1e25, np.zeros_like(theta)
        return -lml, -g

    for th0 in starts:
        res = minimize(objective, np.clip(th0, bounds[:, 0], bounds[:, 1]), jac=True, method="L-BFGS-B",
                       bounds=bounds, options={} if ftol is None else {"ftol": ftol})
        lml = -float(res.fun)
        if best is None or lml > best_lml:
            best, best_lml = np.asarray(res.x, float), lml
    return best, best_lml


def _at_bounds(theta: np.ndarray, bounds: np.ndarray, j: int) -> list[str]:
    names = ["sf2", *[f"length_scale[{i}]" for i in range(len(theta) - 2)], "sn2"]
    out = []
    for name, th, (lo, hi) in zip(names, theta, bounds):
        for side, b in (("lower", lo), ("upper", hi)):
            if np.isclose(th, b):
                out.append(f"output {j}: {name} = {math.exp(th):.3g} is at its {side} bound {math.exp(b):.3g}")
    return out


def fit_gp(X: np.ndarray, Y: np.ndarray, *, restarts: int = 2, seed: int = 0,
           noise_floor: float = NOISE_FLOOR, max_points: int | None = None,
           start: GPBase | None = None) -> tuple[GPModel, dict]:
    """Fit one GP per output of ``Y (N, D)`` on inputs ``X (N, d)`` (physical units) -> ``(GPModel, info)``.

    ``max_points`` caps the training set (``subsample_indices``). ``start``: a model of the same
    input and output dimensions whose hyperparameters are the first start (warm start), else the
    kernel's initial point. ``info``: ``fit_time_s`` (D,), ``log_marginal_likelihood`` (D,,
    scaled units), ``length_scales`` (D, d, standardized input units), ``sf2`` and ``sn2`` (D,,
    standardized output units), ``n_points``, ``n_input``, ``kept`` (indices into ``X``),
    ``warm_start`` and the parameters that ended at a bound (``warnings``)."""
    X, Y, kept, n_input = _capped(X, Y, max_points)
    x_mean, x_std, y_mean, y_std = X.mean(0), column_std(X), Y.mean(0), column_std(Y)
    Z, y = (X - x_mean) / x_std, (Y - y_mean) / y_std
    ell, sf2, sn2, times, messages = optimize_hyperparameters(Z, y, restarts=restarts, seed=seed,
                                                              noise_floor=noise_floor, start=start)
    model = GPModel(X, Y, ell, sf2, sn2, x_mean=x_mean, x_std=x_std, y_mean=y_mean, y_std=y_std,
                    noise_floor=noise_floor)
    info = {"fit_time_s": times, "log_marginal_likelihood": model.log_marginal_likelihood().tolist(),
            "length_scales": ell.tolist(), "sf2": sf2.tolist(), "sn2": sn2.tolist(), "n_points": int(X.shape[0]),
            "n_input": int(n_input), "kept": kept.tolist(), "warm_start": start is not None, "warnings": messages}
    return model, info


def optimize_hyperparameters(Z: np.ndarray, y: np.ndarray, *, restarts: int, seed: int, noise_floor: float,
                             start: GPBase | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, list, list]:
    """Type-II ML hyperparameters of each output of standardized ``y (N, D)`` on standardized
    ``Z (N, d)``: ``(ell (D, d), sf2 (D,), sn2 (D,), fit times (s) per output, bound warnings)``.
    Starts: ``start``'s hyperparameters (or the kernel's initial point), then ``restarts`` seeded
    random points (module docstring)."""
    D, d = y.shape[1], Z.shape[1]
    if start is not None and (start.d != d or start.D != D):
        raise ValueError(f"start model has {start.d} inputs and {start.D} outputs, the data {d} and {D}")
    bounds = log_bounds(d, noise_floor)

    def fit_output(j: int) -> tuple[np.ndarray, float]:
        rng = np.random.RandomState(seed)
        first = (np.log(np.concatenate([[start.sf2[j]], start.ell[j], [max(start.sn2[j], noise_floor)]]))
                 if start is not None else initial_theta(d, noise_floor))
        starts = [first] + [rng.uniform(bounds[:, 0], bounds[:, 1]) for _ in range(restarts)]
        t0 = time.perf_counter()
        theta, _ = maximize_lml(Z, np.ascontiguousarray(y[:, j]), starts, bounds,
                                ftol=WARM_FTOL if start is not None else None)
        return theta, time.perf_counter() - t0

    ell, sf2, sn2, times, messages = np.empty((D, d)), np.empty(D), np.empty(D), [], []
    for j, (theta, seconds) in enumerate(map_outputs(fit_output, D)):   # outputs are independent
        times.append(seconds)
        messages += _at_bounds(theta, bounds, j)
        sf2[j], ell[j], sn2[j] = math.exp(theta[0]), np.exp(theta[1:-1]), math.exp(theta[-1])
    return ell, sf2, sn2, times, messages


def fit_sparse_gp(X: np.ndarray, Y: np.ndarray, *, inducing: int, restarts: int = 2, seed: int = 0,
                  noise_floor: float = NOISE_FLOOR, max_points: int | None = None,
                  start: GPBase | None = None) -> tuple[SparseGPModel, dict]:
    """A sparse GP (FITC, ``raico.plants.gp.SparseGPModel``) on ``X (N, d)``, ``Y (N, D)`` (physical) with
    ``inducing`` inducing points -> ``(SparseGPModel, info)``, ``info`` as :func:`fit_gp`'s plus
    ``n_inducing`` and ``n_hyper`` (points the hyperparameters were optimized on).

    The training set is capped as in :func:`fit_gp`; the scaling is that of the (capped) training
    set. Hyperparameters: the exact GP's likelihood maximized (as :func:`fit_gp`, same starts) on
    the ``min(N, inducing)`` points ``subsample_indices`` keeps (the most recent half, then
    farthest-point among the older), so an optimizer step costs ``O(M^3)``, not ``O(N^3)``.
    Inducing inputs: ``select_inducing`` (greedy maximum variance) among all training inputs at
    those hyperparameters. ``ValueError`` when ``inducing`` is not in ``[1, N]``."""
    X, Y, kept, n_input = _capped(X, Y, max_points)
    if not 1 <= inducing <= X.shape[0]:
        raise ValueError(f"inducing points ({inducing}) must be in [1, {X.shape[0]}], the training points")
    x_mean, x_std, y_mean, y_std = X.mean(0), column_std(X), Y.mean(0), column_std(Y)
    sub = subsample_indices(X, inducing)
    Z, y = (X[sub] - x_mean) / x_std, (Y[sub] - y_mean) / y_std
    ell, sf2, sn2, times, messages = optimize_hyperparameters(Z, y, restarts=restarts, seed=seed,
                                                              noise_floor=noise_floor, start=start)
    model = SparseGPModel(X, Y, ell, sf2, sn2, inducing=inducing, x_mean=x_mean, x_std=x_std, y_mean=y_mean,
                          y_std=y_std, noise_floor=noise_floor)
    info = {"fit_time_s": times, "log_marginal_likelihood": model.log_marginal_likelihood().tolist(),
            "length_scales": ell.tolist(), "sf2": sf2.tolist(), "sn2": sn2.tolist(), "n_points": int(X.shape[0]),
            "n_input": int(n_input), "kept": kept.tolist(), "warm_start": start is not None, "warnings": messages,
            "n_inducing": model.M, "n_hyper": int(len(sub))}
    return model, info


def refit_fixed(model: GPBase, X: np.ndarray, Y: np.ndarray) -> GPBase:
    """A new model of ``model``'s kind on ``X (N, d)``, ``Y (N, D)`` with its hyperparameters and scaling,
    factorized from scratch (a sparse model selects its inducing inputs again, up to ``m_requested``)."""
    X, Y = _check_xy(X, Y)
    if isinstance(model, SparseGPModel):
        return SparseGPModel(X, Y, model.ell, model.sf2, model.sn2, inducing=min(model.m_requested, len(X)),
                             x_mean=model.x_mean, x_std=model.x_std, y_mean=model.y_mean, y_std=model.y_std,
                             noise_floor=model.noise_floor)
    return GPModel(X, Y, model.ell, model.sf2, model.sn2, x_mean=model.x_mean, x_std=model.x_std,
                   y_mean=model.y_mean, y_std=model.y_std, noise_floor=model.noise_floor)


def subsample_indices(X: np.ndarray, max_points: int, *, recent_fraction: float = 0.5) -> np.ndarray:
    """Sorted indices ``(min(N, max_points),)`` of the rows of ``X (N, d)`` to keep (the rule: docs/learning.md)."""
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


def rmse(model: GPBase | AngleInputGP, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
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
    full: GPBase
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


def _capped(X: np.ndarray, Y: np.ndarray, max_points: int | None
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Checked ``X, Y`` capped at ``max_points`` rows (``subsample_indices``), the kept row indices and
    the number of rows given."""
    X, Y = _check_xy(X, Y)
    n_input = X.shape[0]
    kept = np.arange(n_input)
    if max_points is not None and n_input > max_points:
        kept = subsample_indices(X, max_points)
        X, Y = X[kept], Y[kept]
    return X, Y, kept, n_input


def _check_xy(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    X, Y = np.asarray(X, float), np.asarray(Y, float)
    if X.ndim != 2 or Y.ndim != 2 or X.shape[0] != Y.shape[0]:
        raise ValueError(f"expected X (N, d) and Y (N, D), got {X.shape} and {Y.shape}")
    if X.shape[0] == 0:
        raise ValueError("no training data")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
        raise ValueError("training data must be finite")
    return X, Y
