"""GP timings (prints a dict): mean, variance and all input gradients along a trajectory,
the incremental update against a full refactorization, and what the training-set cap costs.

    .venv/bin/python -m bench.gp_bench [--repeats 5] [--no-cap-cost]

BioRob-like sizes: ``N = 1000`` training points, ``M = 500`` query points along a smooth
trajectory, ``d = 15`` inputs (5 joints: q, qdot, u), ``D = 5`` outputs. Hyperparameters are set,
not fitted (the cost does not depend on their values). Medians of ``repeats`` runs, wall time and
process CPU time (the machine may be shared: CPU time is the better single-core figure then).

``mean_var_all_gradients_ms_per_output`` (the headline figure, target 20 ms): one
``GPModel.predict_with_gradients`` call at the ``M`` points (mean, latent variance, their gradients with
respect to all ``d`` inputs, every output) divided by ``D``, with one BLAS thread (the project's policy
per process, ``raico/plants/threads.py``); ``..._2threads`` and ``..._2threads_solves_only`` (a bench-only
patch, ``_solves_on_threads``) the same call with two BLAS threads, for information. ``sparse``: the
same call on the sparse GP (FITC) with ``M_SPARSE`` inducing points and its cost in accuracy against the
exact GP (:func:`bench_sparse`). Where the time goes, what was tried and rejected: docs/benchmarks.md,
"The GP timings".

``mean_and_gradient_ms_per_output``: ``mean_with_gradients``; ``mean_and_variance_ms_per_output``:
``predict`` (one triangular solve per output). ``cap_cost``: held-out RMSE of
``fit_gp(..., max_points=500)`` against the exact GP on all 2000 points at the same
hyperparameters (``raico.stages.fit.gp_fit.measure_cap_cost``) on pendulum trajectories (time-ordered,
analytic pendulum, semi-implicit Euler at 10 ms) and on the synthetic biorob-like data (first
output). Not a test: nothing here fails on a slow machine.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np
from threadpoolctl import ThreadpoolController, threadpool_limits

from raico.plants.gp import GPModel, SparseGPModel
from raico.stages.fit.gp_fit import measure_cap_cost

N, M, N_NEW, N_Q = 1000, 500, 100, 5
M_SPARSE = (100, 200, 300)  # inducing points of the sparse GP rows
TARGET_MS_PER_OUTPUT = 20.0


def _data(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Biorob-like inputs ``(n, 15)`` and smooth targets ``(n, 5)`` (synthetic)."""
    X = np.hstack([rng.uniform(-1.5, 1.5, (n, N_Q)), rng.normal(0, 2, (n, N_Q)), rng.uniform(-10, 10, (n, N_Q))])
    Y = np.sin(X[:, :N_Q]) * 9.81 - X[:, N_Q:2 * N_Q] + X[:, 2 * N_Q:] + 0.3 * np.cos(X[:, [1, 2, 3, 4, 0]])
    return X, Y


def _pendulum_episodes(n_ep: int, T: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Pendulum ``(q, qdot, u)`` rows ``(n_ep T, 3)`` and ``qddot`` ``(n_ep T, 1)`` under random piecewise-linear torques."""
    rng, dt, rows = np.random.default_rng(seed), 0.01, []
    for _ in range(n_ep):
        q, v = rng.uniform(-0.5, 0.5), 0.0
        knots, tk = rng.uniform(-6.0, 6.0, 6), np.linspace(0.0, T * dt, 6)
        for k in range(T):
            u = float(np.interp(k * dt, tk, knots))
            a = u - v - 9.81 * np.sin(q)
            rows.append((q, v, u, a))
            v += dt * a
            q += dt * v
    R = np.array(rows)
    return R[:, :3], R[:, 3:]


def bench_cap_cost(n_points: int = 2000, max_points: int = 500) -> dict:
    """``measure_cap_cost`` on pendulum trajectories and on the biorob-like data (first output)."""
    out = {}
    X, Y = _pendulum_episodes(n_points // 100, 100, 0)
    Xt, Yt = _pendulum_episodes(3, 100, 1)
    out["pendulum"] = measure_cap_cost(X, Y, Xt, Yt, max_points=max_points)
    rng = np.random.default_rng(1)
    X, Y = _data(n_points, rng)
    Xt, Yt = _data(300, rng)
    out["biorob_like_output0"] = measure_cap_cost(X, Y[:, :1], Xt, Yt[:, :1], max_points=max_points)
    return out


def _trajectory(m: int) -> np.ndarray:
    """Query points ``(m, 15)`` along a smooth path through the data region."""
    t = np.linspace(0, 1, m)[:, None]
    phase = np.arange(3 * N_Q)[None, :]
    return np.hstack([np.sin(2 * np.pi * t + phase[:, :N_Q]), 2 * np.cos(2 * np.pi * t + phase[:, :N_Q]),
                      8 * np.sin(4 * np.pi * t + phase[:, :N_Q])])


def _median_ms(fn: Callable[[], object], repeats: int, setup: Callable[[], object] | None = None) -> tuple[float, float]:
    """Median wall and CPU time (ms) of ``fn(setup())`` (or ``fn()``), setup not timed."""
    wall, cpu = [], []
    for _ in range(repeats):
        arg = setup() if setup else None
        t0, c0 = time.perf_counter(), time.process_time()
        fn(arg) if setup else fn()  # type: ignore[call-arg]
        wall.append(1e3 * (time.perf_counter() - t0))
        cpu.append(1e3 * (time.process_time() - c0))
    return statistics.median(wall), statistics.median(cpu)


@contextmanager
def _solves_on_threads(model: GPModel, n: int) -> Iterator[None]:
    """Within: ``model``'s two triangular solves (``_solve_fwd``, ``_solve_bwd``) run on ``n`` BLAS
    threads, everything else on what the caller set (a bench-only instance patch, undone on exit)."""
    ctl = ThreadpoolController()

    def on_threads(fn: Callable) -> Callable:
        def wrapped(*args):
            with ctl.limit(limits=n, user_api="blas"):
                return fn(*args)
        return wrapped

    model._solve_fwd, model._solve_bwd = on_threads(model._solve_fwd), on_threads(model._solve_bwd)
    try:
        yield
    finally:
        del model._solve_fwd, model._solve_bwd


def bench_sparse(model: GPModel, Xq: np.ndarray, repeats: int, X_test: np.ndarray, Y_test: np.ndarray) -> dict:
    """The sparse GP (FITC, ``SparseGPModel``) on ``model``'s data, hyperparameters and scaling, per
    inducing count in ``M_SPARSE``: ``predict_with_gradients`` at ``Xq`` per output (ms, one BLAS
    thread as the caller set), the time to build it (selection + factorization, ms) and its error
    against ``model``: held-out RMSE ratio (sparse / exact, per output) on ``X_test, Y_test``, and
    along ``Xq`` the largest mean difference and predictive-std difference, both over the output's
    training std ``y_std``, and the median ratio of the predictive stds."""
    exact = model.predict_with_gradients(Xq)
    e_test = np.sqrt(np.mean((model.predict_mean(X_test) - Y_test) ** 2, axis=0))
    out = {}
    for m in M_SPARSE:
        def build(m: int = m) -> SparseGPModel:
            return SparseGPModel(model.X, model.Y, model.ell, model.sf2, model.sn2, inducing=m, x_mean=model.x_mean,
                                 x_std=model.x_std, y_mean=model.y_mean, y_std=model.y_std)
        build_ms = _median_ms(build, max(1, repeats // 2))[0]
        sp = build()
        sp.predict_with_gradients(Xq)
        t = _median_ms(lambda sp=sp: sp.predict_with_gradients(Xq), repeats)
        got = sp.predict_with_gradients(Xq)
        e_sp = np.sqrt(np.mean((sp.predict_mean(X_test) - Y_test) ** 2, axis=0))
        sd_e, sd_s = np.sqrt(exact[1]), np.sqrt(got[1])
        out[str(m)] = {"n_inducing": sp.M, "mean_var_all_gradients_ms_per_output": t[0] / model.D,
                       "mean_var_all_gradients_cpu_ms_per_output": t[1] / model.D, "build_ms": build_ms,
                       "heldout_rmse_ratio": (e_sp / e_test).tolist(),
                       "trajectory_max_mean_diff_over_ystd": float(np.max(np.abs(got[0] - exact[0]) / model.y_std)),
                       "trajectory_max_std_diff_over_ystd": float(np.max(np.abs(sd_s - sd_e) / model.y_std)),
                       "trajectory_median_std_ratio": float(np.median(sd_s / sd_e))}
    return out


def bench_gp(repeats: int = 5, cap_cost: bool = True) -> dict:
    """Timings (ms, medians of ``repeats``) of the GP posterior at ``N = 1000``, ``M = 500``, ``d = 15``, ``D = 5``
    (one BLAS thread; ``..._2threads`` with two, ``..._2threads_solves_only`` with two in the triangular solves only).

    With ``cap_cost`` (about 10 s more) also ``bench_cap_cost()``."""
    rng = np.random.default_rng(0)
    X, Y = _data(N + N_NEW, rng)
    ell = rng.uniform(1.5, 4.0, (N_Q, 3 * N_Q))  # standardized input units
    with threadpool_limits(1):
        model = GPModel(X[:N], Y[:N], ell, sf2=np.ones(N_Q), sn2=np.full(N_Q, 1e-4))
        Xq = _trajectory(M)
        model.predict_with_gradients(Xq)  # warm up
        D = model.D
        full = _median_ms(lambda: model.predict_with_gradients(Xq), repeats)
        mean_grad = _median_ms(lambda: model.mean_with_gradients(Xq), repeats)
        mean_var = _median_ms(lambda: model.predict(Xq), repeats)
        upd = _median_ms(lambda m: m.update(X[N:], Y[N:]), repeats, setup=model.copy)
        refit = _median_ms(lambda: GPModel(X, Y, model.ell, model.sf2, model.sn2, x_mean=model.x_mean,
                                            x_std=model.x_std, y_mean=model.y_mean, y_std=model.y_std), repeats)
        X_test, Y_test = _data(300, np.random.default_rng(7))
        sparse = bench_sparse(model, Xq, repeats, X_test, Y_test)
        cap = bench_cap_cost() if cap_cost else None
    with threadpool_limits(2):
        model.predict_with_gradients(Xq)  # warm up the second BLAS thread
        full2 = _median_ms(lambda: model.predict_with_gradients(Xq), repeats)
    with threadpool_limits(1), _solves_on_threads(model, 2):
        model.predict_with_gradients(Xq)
        full2s = _median_ms(lambda: model.predict_with_gradients(Xq), repeats)
    return {
        "sizes": {"N": N, "M": M, "d": model.d, "D": D, "n_new": N_NEW},
        "mean_var_all_gradients_ms_per_output": full[0] / D,
        "mean_var_all_gradients_cpu_ms_per_output": full[1] / D,
        "target_ms_per_output": TARGET_MS_PER_OUTPUT,
        "mean_var_all_gradients_ms_per_output_2threads": full2[0] / D,
        "mean_var_all_gradients_cpu_ms_per_output_2threads": full2[1] / D,  # CPU time of both threads
        "mean_var_all_gradients_ms_per_output_2threads_solves_only": full2s[0] / D,
        "mean_and_gradient_ms_per_output": mean_grad[0] / D,
        "mean_and_variance_ms_per_output": mean_var[0] / D,
        "update_100_ms": upd[0], "update_100_cpu_ms": upd[1],
        "refit_1100_ms": refit[0], "refit_1100_cpu_ms": refit[1],
        "refit_over_update": refit[0] / upd[0],
        "sparse": sparse,
        "cap_cost": cap,
        "repeats": repeats, "cpus": os.cpu_count(), "load_average_1min": os.getloadavg()[0],
    }


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--no-cap-cost", action="store_true", help="skip the training-set cap measurement")
    args = ap.parse_args(argv)
    out = bench_gp(args.repeats, cap_cost=not args.no_cap_cost)
    print(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
