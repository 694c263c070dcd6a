"""Joint ranges as truncated-Gaussian (EP) messages against the augmented Lagrangian:
``python -m bench.truncated_candidate [--iterations N] [--problems a,b] [--out FILE.json]``.

:func:`rows` plans a few problems where a joint range binds with bounded R-AICO (robust schedule) once per
method (:data:`METHODS`: the augmented Lagrangian, the default; EP at AICO's own temperature and colder) and
returns one row per (problem, method): final cost, largest excess over the ranges (rad, against the box a
plan from the start can keep, ``Bounds.position_box``) and the velocity limits (rad/s), the first iteration
from which every later iterate is inside by 1e-3, the iterations run, status and CPU time. ``main`` prints
them as a Markdown table (the docs' numbers) and writes them as JSON. :func:`register_candidates` adds EP to
``bench.constraint_candidates``'s registry (its rows, its format): one call.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = {   # label: problem file (a joint range binds in each)
    "kinova-own-start": "raico/problems/crocoddyl/kinova_reach.toml",
    "kinova-in-range": "raico/problems/crocoddyl/kinova_reach_in_range.toml",
    "talos-arm": "raico/problems/crocoddyl/talos_arm_reach.toml",
    "kinova-near": "raico/problems/suite/kinova_near.toml",
}
METHODS = {    # label: AICOOptions on top of the problem file's defaults (EP: undamped unless said)
    "AL (default)": {},
    "EP T=1": {"ranges": "ep", "ep_temperature": 1.0},
    "EP T=1 damped 0.5": {"ranges": "ep", "ep_temperature": 1.0, "ep_damping": 0.5},
    "EP T=1 to 1e-2": {"ranges": "ep", "ep_temperature": 1.0, "ep_temperature_min": 1e-2},
    "EP T=1 to 1e-2 damped 0.5": {"ranges": "ep", "ep_temperature": 1.0, "ep_temperature_min": 1e-2,
                                  "ep_damping": 0.5},
    "EP T=1 to 1e-4": {"ranges": "ep", "ep_temperature": 1.0, "ep_temperature_min": 1e-4},
}
INSIDE = 1e-3   # rad, rad/s: "inside" for the iterations-to-inside column


CANDIDATES = {   # name: (label, AICOOptions over the default plan's) for bench.constraint_candidates
    "ep": ("ranges as EP messages, T = 1", {"ranges": "ep", "ep_temperature": 1.0}),
    "ep-anneal": ("ranges as EP messages, T = 1 to 0.01, damped 0.5",
                  {"ranges": "ep", "ep_temperature": 1.0, "ep_temperature_min": 1e-2, "ep_damping": 0.5}),
}


def _has_ranges(problem) -> bool:  # noqa: ANN001
    b = problem.bounds
    return b is not None and (b.has_positions or b.has_velocities)


def _run_ep(problem, options: dict, init: dict, callback, over: dict):  # noqa: ANN001, ANN201
    """``aico`` with the default plan's options (those AICO knows) and ``over``."""
    from raico.planning.aico import AICOOptions, aico

    keys = set(AICOOptions.field_names())
    return aico(problem, AICOOptions(**{k: v for k, v in {**options, **over}.items() if k in keys}),
                callback=callback, **init)


def register_candidates(registry: Any = None) -> None:
    """Register :data:`CANDIDATES` in ``registry`` (default ``bench.constraint_candidates``; the module itself when
    it runs as ``__main__``: ``Candidate(name, label, applies, run)``, ``run(problem, options, init, callback)``),
    where a problem has joint ranges or velocity limits."""
    import functools

    if registry is None:
        import bench.constraint_candidates as registry
    for name, (label, over) in CANDIDATES.items():
        registry.register(registry.Candidate(name, label, _has_ranges, functools.partial(_run_ep, over=over)))


def _excess(problem, X: np.ndarray) -> tuple[float, float]:
    """The largest excess of ``X`` over the position box a plan from the start can keep and over the velocity
    limits (0 inside)."""
    b = problem.bounds
    q = v = 0.0
    if b is not None and b.has_positions:
        dt = float(getattr(problem.dynamics, "dt", 1.0))
        lo, hi = b.position_box(problem.x0, dt, problem.T)
        Q = X[1:, b.q_index]
        q = float(max(0.0, np.max(Q - hi[1:]), np.max(lo[1:] - Q)))
    if b is not None and b.has_velocities:
        v = float(b.velocity_violation(X))
    return q, v


def plan_once(file: str, extra: dict, iterations: int) -> dict:
    """One bounded R-AICO plan of ``file`` with the options ``extra``; the row of :func:`rows`."""
    from raico.planning.solvers import solve
    from raico.stages.plan.stage import PlanConfig, build_problem, quasi_static_controls

    cfg = PlanConfig(problem=str(ROOT / file), solver="raico", alpha_schedule="robust", bounds="hard",
                     iterations=int(iterations)).normalized()
    _, _, problem, q0, _ = build_problem(cfg)
    init = {}
    if cfg.start == "rollout":
        init["U_init"] = np.zeros((problem.T, problem.n_u))
    elif cfg.start == "quasi-static":
        init["U_init"] = quasi_static_controls(problem, q0)
    outside: list[int] = []

    def cb(rec, X, U) -> None:  # noqa: ANN001
        if max(_excess(problem, X)) > INSIDE:
            outside.append(rec.iteration)

    t0 = time.process_time()
    res = solve(problem, "raico", {**cfg.solver_options(), **extra}, callback=cb, **init)
    cpu = time.process_time() - t0
    q, v = _excess(problem, res.X) if np.all(np.isfinite(res.X)) else (np.inf, np.inf)
    inside_from = None if max(q, v) > INSIDE else (max(outside) + 1 if outside else 1)
    return {"final_cost": float(problem.cost(res.X, res.U)), "range_excess": q, "velocity_excess": v,
            "inside_from": inside_from, "iterations": res.iterations, "status": res.status.value,
            "cpu_s": cpu, "message": res.message}


def rows(problems: dict[str, str] | None = None, methods: dict[str, dict] | None = None,
         iterations: int = 200) -> list[dict]:
    """One row per (problem, method): ``{"problem", "method", "final_cost", "range_excess", "velocity_excess",
    "inside_from", "iterations", "status", "cpu_s", "message"}`` (``inside_from``: the first iteration from
    which every iterate is inside by ``INSIDE``, ``None`` if the plan is not)."""
    out = []
    for label, file in (problems or PROBLEMS).items():
        for method, extra in (methods or METHODS).items():
            row = {"problem": label, "method": method, **plan_once(file, extra, iterations)}
            print(f"{label:18s} {method:14s} cost {row['final_cost']:.6g} excess {row['range_excess']:.2g} rad "
                  f"{row['velocity_excess']:.2g} rad/s inside from {row['inside_from']} it {row['iterations']} "
                  f"{row['status']} {row['cpu_s']:.1f} s", file=sys.stderr, flush=True)
            out.append(row)
    return out


def lq_rows(iterations: int = 200) -> list[dict]:
    """The bounded LQ problem of the tests (``tests.planning.test_aico_robust.bounded_lq``, T = 12: two state
    coordinates in [-0.3, 0.3], both controls in +-0.8) against its QP's feasible optimum: per method and
    annealing floor, the relative gap, the range excess and the iterations."""
    from raico.planning.aico import AICOOptions, aico
    from tests.planning.test_aico_robust import bounded_lq, bounded_qp_optimum

    _, pb = bounded_lq(T=12)
    qp = bounded_qp_optimum(pb)
    out = []
    variants = [("AL (default)", {})] + [
        (f"EP T=1{'' if f is None else f' to {f:g}'}{' damped 0.5' if d < 1 else ''}",
         {"ranges": "ep", "ep_temperature_min": f, "ep_damping": d})
        for d in (1.0, 0.5) for f in (None, 1e-2, 1e-4, 1e-6)]
    for label, extra in variants:
        res = aico(pb, AICOOptions(iterations=iterations, alpha=1.0, schedule="robust", **extra))
        q, _ = pb.bounds.violation(res.X, res.U)
        out.append({"method": label, "gap": pb.cost(res.X, res.U) / qp - 1.0, "range_excess": q,
                    "iterations": res.iterations, "status": res.status.value})
    return out


def lq_table(rs: list[dict]) -> str:
    """:func:`lq_rows` as a Markdown table."""
    lines = ["| method | cost / QP optimum - 1 | range excess (rad) | iterations | status |", "|" + "---|" * 5]
    lines += [f"| {r['method']} | {r['gap']:.2g} | {r['range_excess']:.2g} | {r['iterations']} | {r['status']} |"
              for r in rs]
    return "\n".join(lines)


def table(rs: list[dict]) -> str:
    """The rows as a Markdown table, each cost also as a ratio to the lowest cost of a plan inside the
    limits on its problem."""
    best: dict[str, float] = {}
    for r in rs:
        if max(r["range_excess"], r["velocity_excess"]) <= INSIDE:
            best[r["problem"]] = min(best.get(r["problem"], np.inf), r["final_cost"])
    lines = ["| problem | method | final cost | / best inside | range excess (rad) | velocity excess (rad/s) "
             "| inside from iteration | iterations | status | CPU s |", "|" + "---|" * 10]
    for r in rs:
        ratio = r["final_cost"] / best[r["problem"]] if r["problem"] in best else float("nan")
        lines.append(f"| {r['problem']} | {r['method']} | {r['final_cost']:.5g} | {ratio:.4f} | "
                     f"{r['range_excess']:.2g} | {r['velocity_excess']:.2g} | {r['inside_from']} | "
                     f"{r['iterations']} | {r['status']} | {r['cpu_s']:.1f} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--iterations", type=int, default=200)
    ap.add_argument("--problems", default="", help="comma-separated labels of PROBLEMS (default all)")
    ap.add_argument("--out", default="", help="write the rows as JSON here")
    ap.add_argument("--lq", action="store_true", help="the bounded LQ problem against its QP only")
    ap.add_argument("--artifacts", default="", help="write both tables as the page artifacts/bench/truncated_candidate.md")
    args = ap.parse_args()
    lq = lq_table(lq_rows(args.iterations))
    if args.lq:
        print(lq)
        return
    load = os.getloadavg()[0]
    probs = {k: PROBLEMS[k] for k in args.problems.split(",")} if args.problems else None
    rs = rows(probs, iterations=args.iterations)
    print(table(rs))
    if args.out:
        Path(args.out).write_text(json.dumps(rs, indent=1))
    if args.artifacts:
        out = Path(args.artifacts) / "bench"
        out.mkdir(parents=True, exist_ok=True)
        (out / "truncated_candidate.md").write_text(page(lq, table(rs), args.iterations, load, os.getloadavg()[0]))


def page(lq: str, problems: str, iterations: int, load0: float, load1: float) -> str:
    """The page of one run: the bounded LQ problem against its QP, then the robot problems."""
    return (f"Measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; machine: {os.cpu_count()} cpus, 1-minute "
            f"load {load0:.1f} at the start and {load1:.1f} at the end (CPU seconds).\n\n"
            "The bounded LQ problem (tests/planning/test_aico_robust.py `bounded_lq`, T = 12) against its QP's "
            f"feasible optimum:\n\n{lq}\n\nProblems where a range binds, bounded R-AICO (robust schedule, "
            f"{iterations} iterations), the augmented Lagrangian against EP (excess against the box a plan from its "
            "start can keep; \"inside from\": the iteration from which every iterate is inside by 1e-3):\n\n"
            f"{problems}\n")


if __name__ == "__main__":
    main()
