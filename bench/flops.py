"""The arithmetic of an R-AICO sweep against the machine: flops from the formulas, the achieved rate,
and a dense ``dgemm`` measured in the same run.

    .venv/bin/python -m bench.flops

:func:`sweep_flops` counts the floating-point operations (a multiply and an add are two) of the
compiled sweep (``raico/planning/csweep.c`` on ``raico/planning/dense.c``) per time step for a state of ``N``
and controls of ``m`` entries: the forward message, the backward message, two beliefs and, at a
repeat of a step, the dynamics' relinearization. ``forward=False`` counts the backward message alone
(the robust schedule, ``theta = inf``), ``block=False`` the dense products of models without the
semi-implicit Euler step's block form. Lower-order terms are left out (the count is a floor);
``tests/bench/test_bench_flops.py`` checks each part's cubic term against a literal count. The
formulas term by term: docs/benchmarks.md, "The sweep's flops, term by term".

:func:`dgemm_rate` times numpy's ``matmul`` (OpenBLAS) on square matrices with one BLAS thread: this
machine's single-core dense rate, the physical limit the sweeps are compared with. The achieved
rate is the sweep's flops over the whole iteration's time (rollout, linearization, cost included),
so it is a lower bound of the sweep's own rate.
"""

from __future__ import annotations

import statistics
import time

import numpy as np


def sweep_flops(N: int, m: int, T: int, repeats: float = 0.0, block: bool = True, forward: bool = True) -> dict:
    """Flops of one R-AICO sweep: per time step, per iteration (``T`` steps and ``repeats`` repeats of
    a step) and by part; ``block``: the semi-implicit Euler block form (else the dense products);
    ``forward``: the forward messages and beliefs run at every step (else the backward messages alone)."""
    K, h = m + N + 1, N / 2
    vstar = N ** 3 / 3 + 2 * N ** 2 * (N + 1)
    control = m ** 3 / 3 + 2 * m ** 2 * (N + 1) + m * N ** 2
    if block:
        products = 2 * h * h * m + 2 * h * h * N + h * N ** 2 + 2 * h * h * N + 2 * m * h * K + 2 * N ** 2
        relin = 2 * h * m * m + h * h * m
    else:
        products = 2 * N * (N + 1) * K + 2 * m * N * K + 2 * N ** 2 * (N + 1)
        relin = 2 * N * m * m + 2 * N * N * m
    parts = {
        "forward": N ** 3 / 3 + N ** 3 + N ** 3 + N ** 3 / 3 + 2 * N ** 3 / 3,
        "backward": vstar + products + control,
        "beliefs": 2 * (N ** 3 / 3 + 2 * N ** 2),
        "dynamics relinearization": relin,
    }
    per_step = float(parts["backward"] + (parts["forward"] + parts["beliefs"] if forward else 0.0))
    per_repeat = parts["dynamics relinearization"] + parts["beliefs"] / 2 if forward else 0.0
    return {"per_step": per_step, "per_iteration": per_step * T + per_repeat * repeats,
            "parts": {k: float(v) for k, v in parts.items()}}


def dgemm_rate(size: int = 384, reps: int = 5) -> float:
    """GFLOP/s of one ``size x size`` matrix product (``2 size^3`` flops) with one BLAS thread,
    the median of ``reps`` timings after a warm-up."""
    from threadpoolctl import threadpool_limits

    rng = np.random.default_rng(0)
    A, B = rng.standard_normal((size, size)), rng.standard_normal((size, size))
    out = np.empty((size, size))
    with threadpool_limits(limits=1, user_api="blas"):
        np.matmul(A, B, out=out)
        times = []
        for _ in range(reps):
            t0 = time.perf_counter()
            np.matmul(A, B, out=out)
            times.append(time.perf_counter() - t0)
    return 2.0 * size ** 3 / statistics.median(times) / 1e9


def backward_sweep_rate(problem, reps: int = 5) -> dict:
    """The message arithmetic on its own: one compiled backward sweep of ``problem`` at a fixed linearization
    (the start held, no relinearization: ``theta = inf``), timed ``reps`` times after a warm-up. Returns its
    ``seconds`` (median, one thread), its ``flops`` (``T`` backward messages by :func:`sweep_flops`) and
    ``gflops``; the achieved rate of the sweeps themselves, where :func:`flop_fields` divides by the whole
    iteration (dynamics derivatives, rollouts and costs included)."""
    from raico.planning.aico.sweeps import backward_sweep_at_start
    from raico.planning.problem import single_threaded_blas

    with single_threaded_blas():
        sweep, block = backward_sweep_at_start(problem)
        sweep()
        times = []
        for _ in range(reps):
            t0 = time.perf_counter()
            sweep()
            times.append(time.perf_counter() - t0)
    seconds = statistics.median(times)
    flops = sweep_flops(len(problem.x0), problem.n_u, problem.T, block=block)["parts"]["backward"] * problem.T
    return {"seconds": seconds, "flops": flops, "gflops": flops / seconds / 1e9, "block": block}


def flop_fields(N: int, m: int, T: int, seconds_per_iteration: float, dgemm_gflops: float,
                repeats: float = 0.0, forward: bool = True) -> dict:
    """The flop columns of an R-AICO row (``repeats``: per iteration; ``forward``: see :func:`sweep_flops`):
    flops per step and per iteration, the achieved GFLOP/s and its ratio to the measured ``dgemm`` rate."""
    f = sweep_flops(N, m, T, repeats, forward=forward)
    gflops = f["per_iteration"] / seconds_per_iteration / 1e9
    return {"flops_per_step": f["per_step"], "flops_per_iteration": f["per_iteration"],
            "gflops": gflops, "dgemm_gflops": dgemm_gflops, "ratio_to_dgemm": gflops / dgemm_gflops}


if __name__ == "__main__":
    rate = dgemm_rate()
    print(f"dgemm (one thread): {rate:.1f} GFLOP/s")
    for n in (2, 4, 8, 16, 32):
        f, b = sweep_flops(2 * n, n, 100), sweep_flops(2 * n, n, 100, forward=False)
        print(f"chain of {n:2d} joints: {f['per_step'] / n ** 3:6.1f} n^3 = {f['per_step']:.3g} flops per step "
              f"({b['per_step'] / n ** 3:.1f} n^3 for the backward message alone), {f['per_iteration']:.3g} per "
              f"iteration (T = 100)")
