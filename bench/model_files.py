"""Robots from model files: load times and per-iteration time against the number of joints, R-AICO against
FDDP like for like.

    .venv/bin/python -m bench.model_files [--artifacts artifacts] [--part loads|robots|scaling ...]

writes ``artifacts/bench/model_files.json`` and ``model_files.md`` (:func:`markdown_page`; the ``models`` block
of docs/benchmarks.md, ``scripts/readme_numbers.py``); ``make bench`` runs it too (bench/run.py).

- **First load** of a robot from its file in a fresh process with an empty kernel folder (the file parsed
  into Drake, the tree kernels generated, compiled and checked, the planning problem built). Targets: a
  7-DOF arm (xArm7) <= 10 s, a 30-DOF humanoid (Talos on a welded sole) <= 60 s; **a later process** with
  the kernels on disk: <= 1 s (the interpreter's start and imports not counted).
- **Like for like**: every time per iteration is the median of the iterations' own wall times as the solvers
  record them (FDDP's records made after crocoddyl's solve); the setup before the first iteration is a column
  of its own (:func:`timed_solve`), and beside every row each solver's time to the common cost
  (:func:`common_cost`; "not reached": a run that never got there).
- **Scaling**: a serial chain of n links (n = 2 to 32, a URDF written here), a reach of its tip with
  analytic dynamics (T = 100, dt = 0.01): seconds per R-AICO and per FDDP iteration, with the exponent of a
  least-squares line through log(time) against log(n), over every size and over n >= 8 (where the dense
  O(n^3) algebra should show). The chain and its costs: docs/benchmarks.md, "The chain in detail".
- **Robots** (the Kinova, UR5 and xArm7 problem files, T = 100): R-AICO's and FDDP's time per iteration and
  setup, their ratio, each one's time to the common cost; a solver that fails on a robot keeps its row with the
  reason (and a line on stderr).
- **Flops**: beside every R-AICO row, the flops of the sweep its iterations run (:mod:`bench.flops`; the robust
  schedule: the backward messages alone), the achieved GFLOP/s over the iteration's own time and its ratio to a
  one-thread dgemm measured in the same run (a row of its own).

Not a test: nothing here fails on a slow machine.
"""

from __future__ import annotations

import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path
from typing import Any

import numpy as np

CHAIN_SIZES = (2, 4, 8, 16, 32)
CHAIN_T = 100
ITERATIONS = 4

_LOAD = textwrap.dedent("""
    import json, sys, time
    t0 = time.perf_counter()
    from raico.stages.plan.stage import PlanConfig, build_problem
    t_import = time.perf_counter()
    cfg = PlanConfig(problem=sys.argv[1], iterations=1).normalized()
    cfg.validate()
    build_problem(cfg)
    from raico.plants.fast_analytic import make_fast_or_exact
    from raico.stages.plan.stage import robot_and_task
    robot, task = robot_and_task(cfg)
    dyn = make_fast_or_exact(robot, task.dt)
    print(json.dumps({"load_s": time.perf_counter() - t_import, "import_s": t_import - t0,
                      "route": type(dyn).__name__, "n": robot.n_q}))
""")


def _load_in_process(problem: Path, kernels: Path) -> dict:
    env = {**os.environ, "RAICO_KERNEL_DIR": str(kernels)}
    out = subprocess.run([sys.executable, "-c", _LOAD, str(problem)], capture_output=True, text=True, env=env,
                         check=True, cwd=Path(__file__).resolve().parents[1])
    return json.loads(out.stdout.strip().splitlines()[-1])


def load_rows(reps: int = 3) -> list[dict]:
    """First load (empty kernel folder) and a later process's load, per robot, medians of ``reps``."""
    from raico.plants.model_file import example_robot_data

    if example_robot_data() is None:
        return []
    root = Path(__file__).resolve().parents[1]
    cases = [("xArm7 (7 joints)", root / "raico/problems/examples/xarm7_reach.toml", 10.0),
             ("Talos on its right sole (32 joints)", root / "raico/problems/crocoddyl/talos_taichi.toml", 60.0)]
    rows = []
    for name, problem, target in cases:
        first, later = [], []
        for _ in range(reps):
            with tempfile.TemporaryDirectory() as kernels:
                first.append(_load_in_process(problem, Path(kernels)))
                later.append(_load_in_process(problem, Path(kernels)))
        for label, samples, tgt in (("first load", first, target), ("a later process", later, 1.0)):
            s = [r["load_s"] for r in samples]
            med = statistics.median(s)
            rows.append({"benchmark": f"{name}: {label} (repairs, parse, kernels, problem; route "
                                      f"{samples[0]['route']})", "median_s": med, "samples_s": s,
                         "target_s": tgt, "ratio_to_target": med / tgt})
    return rows


# ------------------------------------------------------------------ scaling with the number of joints
def chain_urdf(n: int) -> str:
    """A serial chain of ``n`` revolute joints hanging from its base (pitch, roll, pitch, ...: every axis
    across its link), 0.2 m links of 1 kg, a tip frame 0.2 m below the last joint; efforts up to 1000 N m
    (holding the 32-joint chain at its start takes 157 N m at its base)."""
    links = ['<link name="base"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" '
             'ixz="0" iyz="0"/></inertial></link>']
    parent = "base"
    for k in range(n):
        axis = "0 1 0" if k % 2 == 0 else "1 0 0"
        links.append(f'<joint name="j{k}" type="revolute"><parent link="{parent}"/><child link="l{k}"/>'
                     f'<origin xyz="0 0 {-0.2 if k else -0.05}"/><axis xyz="{axis}"/>'
                     f'<limit lower="-3" upper="3" effort="1000" velocity="10"/></joint>')
        links.append(f'<link name="l{k}"><inertial><origin xyz="0 0 -0.1"/><mass value="1"/>'
                     f'<inertia ixx="0.004" iyy="0.004" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial></link>')
        parent = f"l{k}"
    links.append(f'<joint name="tip_joint" type="fixed"><parent link="{parent}"/><child link="tip"/>'
                 '<origin xyz="0 0 -0.2"/></joint><link name="tip"/>')
    return '<?xml version="1.0"?>\n<robot name="chain">' + "".join(links) + "</robot>\n"


def chain_start(n: int) -> dict[str, float]:
    """The start posture (rad): a zigzag, ``+0.3, +0.1, -0.3, -0.1`` on pitch, roll, pitch, roll, ...: bent at
    every joint (no singular straight chain), every link within 0.3 rad of hanging straight down."""
    return {f"j{k}": (0.3 if k % 2 == 0 else 0.1) * (1 if k % 4 < 2 else -1) for k in range(n)}


def chain_problem(n: int, folder: Path) -> Path:
    """A problem file: the chain's tip 5 cm from its start at T (a reach as crocoddyl's examples write it: the
    goal, the state kept near the start posture at rest, the torques near the ones that hold it)."""
    urdf = folder / f"chain{n}.urdf"
    urdf.write_text(chain_urdf(n))
    start = ", ".join(f"{j} = {q:g}" for j, q in chain_start(n).items())
    text = textwrap.dedent(f"""
        [robot]
        file = "{urdf.name}"
        start = {{ {start} }}
        armature = 0.01
        [horizon]
        T = {CHAIN_T}
        dt = 0.01
        [dynamics]
        model = "analytic"
        [costs.reach]
        type = "frame_position"
        frame = "tip"
        target = [0.05, 0.0, 0.05]
        relative = "start"
        times = "last"
        weight = 1e4
        [costs.posture]
        type = "state"
        target = "start"
        times = "all"
        weight = 1e-3
        [costs.control]
        type = "control"
        target = "gravity"
        weight = 1e-3
    """)
    path = folder / f"chain{n}.toml"
    path.write_text(text)
    return path


def records_after(solver: str) -> dict:
    """The keyword that keeps raico's bookkeeping out of a crocoddyl solver's iterations (its records made after its
    solve: ``raico.planning.crocoddyl.fddp``'s ``record="after"``); none for raico's own solvers."""
    from raico.planning.solvers import CROCODDYL_SOLVERS

    return {"record": "after"} if solver in CROCODDYL_SOLVERS else {}


def timed_solve(problem, solver: str, options: dict):
    """One solve of ``problem`` and its setup (s): the time from the call to its first iteration's start.

    FDDP: crocoddyl's model built from the problem (``raico.planning.crocoddyl.build``, timed here and handed to
    the solver) and the rollout of its start and its cost (what ``fddp`` does before crocoddyl's solve,
    timed here the same way); its records are made after the solve (``record="after"``: no feedback rollout of
    an infeasible iterate between crocoddyl's iterations). R-AICO and the others: the first callback's
    time, less the call's and the solver's clock at that record (the solver's loop calls it as the iteration's
    clock stops); ``None`` when the first iteration diverged (no callback)."""
    from raico.planning.solvers import solve

    if records_after(solver):
        from raico.planning.crocoddyl import build

        t0 = time.perf_counter()
        cp = build(problem)
        U0 = np.zeros((problem.T, problem.n_u))
        problem.cost(cp.rollout(U0), U0)
        setup = time.perf_counter() - t0
        return solve(problem, solver, options, croc=cp, **records_after(solver)), setup
    first: list[float] = []

    def stamp(rec, *_) -> None:  # noqa: ANN001
        if not first:
            first.append(time.perf_counter() - rec.elapsed_s)   # when the solver's clock started

    t0 = time.perf_counter()
    res = solve(problem, solver, options, callback=stamp)
    return res, (first[0] - t0 if first else None)


def per_iteration_details(problem_file: Path, specs: list[tuple[str, dict]], reps: int = 3) -> list[tuple[dict | None, str]]:
    """Solvers' timed runs on a problem file (without hard bounds, as FDDP: like for like), ``reps`` rounds of one
    solve of each solver in ``specs`` (``(solver, options)``) in turn, so that a shared machine's load falls on
    them alike. Per solver: ``seconds``, the median of the iterations' own wall times as the solvers record them
    (no setup; FDDP's records made after its solve) in the median run (by that median); ``setup_s``, the median
    setup (:func:`timed_solve`: crocoddyl's model built from the problem and the start's rollout; R-AICO's first
    rollout, its cost, the sweeps' buffers); that run's ``costs`` and ``elapsed_s`` per iteration (the solver's
    clock: the iterations' own times summed); the repeats of a step per iteration (R-AICO's relinearizations
    within the sweeps; 0 for the others), how the run ended (``status``; ``ended``: :func:`ending`), its start's
    and its last iteration's cost and the problem's sizes, and ""; or (None, why the solver could not take the
    problem)."""
    from raico.stages.plan.stage import PlanConfig, build_problem

    samples: list[list] = [[] for _ in specs]   # per solver: (own median, setup, repeats, result)
    failed: dict[int, str] = {}
    problem = None
    for _ in range(reps):
        for k, (solver, options) in enumerate(specs):
            if k in failed:
                continue
            _, _, problem, _, _ = build_problem(PlanConfig(problem=str(problem_file), bounds="none").normalized())
            try:
                res, setup = timed_solve(problem, solver, options)
            except Exception as e:  # noqa: BLE001 - a solver that cannot take the problem: no time, said why
                failed[k] = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}".rstrip(": ")
                continue
            times = [h.time_s for h in res.history]
            samples[k].append((float(np.median(times)) if times else float("inf"), setup,
                               sum(getattr(h, "repeats", 0) or 0 for h in res.history) / max(1, res.iterations), res))
    out: list[tuple[dict | None, str]] = []
    for k in range(len(specs)):
        if k in failed:
            out.append((None, failed[k]))
            continue
        runs = sorted(samples[k], key=lambda r: r[0])
        own, _, repeats, res = runs[len(runs) // 2]   # the median run's own repeats, history and ending
        status = str(getattr(res.status, "value", res.status))
        final = float(res.history[-1].cost) if res.history else float("inf")
        timed = [r[1] for r in runs if r[1] is not None]
        out.append(({"seconds": own if res.history else None, "setup_s": float(np.median(timed)) if timed else None,
                     "repeats": repeats, "n_x": problem.n_x, "n_u": problem.n_u, "T": problem.T, "status": status,
                     "start_cost": float(res.initial_cost), "final_cost": final,
                     "costs": [float(h.cost) for h in res.history],
                     "elapsed_s": [float(h.elapsed_s) for h in res.history],
                     "ended": ending(status, float(res.initial_cost), final)}, ""))
    return out


COMMON_WITHIN = 0.01   # the common cost: within 1 % of the better final cost of the two solvers


def common_cost(a: dict, b: dict) -> float | None:
    """The cost both runs ``a`` and ``b`` (details of :func:`per_iteration_details`) are timed to: the better of
    their final costs (a run that diverged or did not descend has none) plus ``COMMON_WITHIN`` of its size;
    ``None`` without a finite final cost."""
    finals = [d["final_cost"] for d in (a, b) if d["ended"] not in ("diverged", "no descent")
              and np.isfinite(d["final_cost"])]
    if not finals:
        return None
    best = min(finals)
    return best + COMMON_WITHIN * abs(best)


def time_to(d: dict, cost: float | None) -> float | None:
    """The solver's clock (s, its iterations' own times summed) when run ``d`` first reached ``cost`` or less;
    ``None``: never (or no common cost)."""
    if cost is None:
        return None
    return next((t for c, t in zip(d.get("costs", []), d.get("elapsed_s", [])) if c <= cost), None)


def fddp_columns(a: dict, f: dict) -> dict:
    """The FDDP columns of an R-AICO row (``a``, ``f``: their details): FDDP's own time per iteration and setup,
    the ratio of the iterations' own times, the common cost and both solvers' times to it."""
    target = common_cost(a, f)
    out = {"fddp_s": f["seconds"], "fddp_setup_s": f["setup_s"], "fddp_final_cost": f["final_cost"],
           "fddp_ended": f["ended"], "common_cost": target,
           "time_to_common_s": time_to(a, target), "fddp_time_to_common_s": time_to(f, target)}
    if a["seconds"] and f["seconds"]:
        out["ratio_to_fddp"] = a["seconds"] / f["seconds"]
    return out


def ending(status: str, start_cost: float, final_cost: float) -> str:
    """How a timed run ended, for the page: ``diverged`` (its status, or a cost that is not finite), ``no
    descent`` (its last cost not below its start's: the time is of iterations that found nothing), else its
    status (``converged``, ``max-iterations``)."""
    if status == "diverged" or not np.isfinite(final_cost):
        return "diverged"
    if np.isfinite(start_cost) and final_cost >= start_cost:
        return "no descent"
    return status


def _exponent(sizes, times) -> float:
    return float(np.polyfit(np.log(sizes), np.log(times), 1)[0])


ROBOTS = (("Kinova reach (crocoddyl)", "raico/problems/crocoddyl/kinova_reach.toml"),
          ("UR5 reach", "raico/problems/examples/ur5_reach.toml"), ("xArm7 reach", "raico/problems/examples/xarm7_reach.toml"))


def _relocates(options: dict) -> bool:
    """Whether R-AICO with ``options`` runs the forward sweep and the beliefs at every step (relinearizations
    within the sweeps: ``theta`` finite, ``max_repeats`` > 0, not the robust schedule, which sets ``theta``
    to inf): else an iteration's sweep is the backward messages alone."""
    from raico.planning.solvers import make_options

    o = make_options("raico", options)
    return o.schedule != "robust" and math.isfinite(o.theta) and o.max_repeats > 0


def flop_columns(detail: dict, dgemm: float | None, problem_file: Path | None = None, forward: bool = True) -> dict:
    """The sweep's flop columns of an R-AICO measurement (bench.flops; ``forward``: :func:`_relocates`), none
    without a dgemm rate; with ``problem_file`` also the backward sweep timed alone (``sweep_alone_*``: the
    message arithmetic's own rate)."""
    if dgemm is None or not detail.get("seconds"):
        return {}
    from bench.flops import backward_sweep_rate, flop_fields

    out = flop_fields(detail["n_x"], detail["n_u"], detail["T"], detail["seconds"], dgemm, detail["repeats"],
                      forward=forward)
    if problem_file is not None:
        from raico.stages.plan.stage import PlanConfig, build_problem

        _, _, problem, _, _ = build_problem(PlanConfig(problem=str(problem_file), bounds="none").normalized())
        alone = backward_sweep_rate(problem)
        out.update(sweep_alone_s=alone["seconds"], sweep_alone_gflops=alone["gflops"],
                   sweep_alone_ratio_to_dgemm=alone["gflops"] / dgemm)
    return out


def _flop_note(f: dict) -> str:
    alone = (f"; the backward sweep alone {f['sweep_alone_gflops']:6.2f} GFLOP/s = "
             f"{100 * f['sweep_alone_ratio_to_dgemm']:5.1f} %" if "sweep_alone_gflops" in f else "")
    return (f"  {f['flops_per_iteration'] / 1e6:8.1f} Mflop/iteration  {f['gflops']:6.2f} GFLOP/s = "
            f"{100 * f['ratio_to_dgemm']:5.1f} % of dgemm" + alone if f else "")


def _ms(x: float | None) -> str:
    return "-" if x is None else f"{x * 1e3:.2f} ms"


def _timing_note(a: dict, f: dict | None = None, row: dict | None = None) -> str:
    """One line of a measurement: its own time per iteration and setup, how it ended, FDDP's beside it and both
    times to the common cost."""
    out = (f"{_ms(a['seconds'])}/iteration, setup {_ms(a['setup_s'])} ({a['ended']}: cost {a['start_cost']:.4g} -> "
           f"{a['final_cost']:.4g}, {a['repeats']:.0f} repeats/iteration)")
    if f is not None and row is not None and "fddp_s" in row:
        ratio = row.get("ratio_to_fddp")
        common, ta, tf = row["common_cost"], row["time_to_common_s"], row["fddp_time_to_common_s"]
        out += (f"  FDDP {_ms(f['seconds'])}, setup {_ms(f['setup_s'])}, ratio "
                f"{'-' if ratio is None else format(ratio, '.2f')}; to within 1 % of "
                f"{'-' if common is None else format(common, '.4g')}: "
                f"{'not reached' if ta is None else _ms(ta)} against {'not reached' if tf is None else _ms(tf)}")
    return out


def _failed(label: str, why: str) -> dict:
    """The row of a solver that could not run the problem: its name, ``ended`` "failed" and the reason (said on
    stderr too): never left out without a word."""
    print(f"  {label}: not timed: {why}", file=sys.stderr, flush=True)
    return {"benchmark": label, "status": "failed", "ended": "failed", "error": why}


def robot_rows(dgemm: float | None = None) -> list[dict]:
    """R-AICO and FDDP on the Kinova, UR5 and xArm7 problems (T = 100): each solver's own time per iteration
    (the iterations' own times) and setup (:func:`timed_solve`), their ratio, the time of each to the common
    cost (:func:`common_cost`), and R-AICO's sweep flops against the dgemm rate. R-AICO runs with what ``raico
    plan`` gives the problem file (:func:`chain_raico_options`). A solver that fails on a robot gives a row
    saying why (and a line on stderr)."""
    from raico.planning.solvers import SOLVERS
    from raico.plants.model_file import example_robot_data

    if example_robot_data() is None:
        return []
    root = Path(__file__).resolve().parents[1]
    rows = []
    for label, rel in ROBOTS:
        options = chain_raico_options(root / rel)
        specs = [("raico", options)] + ([("fddp", {"iterations": ITERATIONS})] if "fddp" in SOLVERS else [])
        (a, why), (f, fwhy) = (per_iteration_details(root / rel, specs) + [(None, "crocoddyl not installed")])[:2]
        if a is None:
            rows.append(_failed(f"{label}: one R-AICO iteration", why))
            continue
        row = {"benchmark": f"{label}: one R-AICO iteration", "median_s": a["seconds"], "samples_s": [a["seconds"]],
               "target_s": None, "ratio_to_target": None, "setup_s": a["setup_s"], "repeats_per_iteration": a["repeats"],
               "status": a["status"], "ended": a["ended"], "final_cost": a["final_cost"],
               **flop_columns(a, dgemm, root / rel, _relocates(options))}
        if f is not None:
            row.update(fddp_columns(a, f))
        else:
            row["fddp_error"] = fwhy
            print(f"  {label}: FDDP not timed: {fwhy}", file=sys.stderr, flush=True)
        rows.append(row)
        print(f"  {label:28s} R-AICO " + _timing_note(a, f, row) + _flop_note(row), flush=True)
    return rows


def chain_raico_options(problem_file: Path) -> dict:
    """R-AICO's options on a problem file (a chain, a robot): the ones ``raico plan`` gives it (its robust
    schedule, alpha 1), every iteration run (``tol_rel = 0``)."""
    from raico.stages.plan.stage import PlanConfig

    cfg = PlanConfig(problem=str(problem_file), iterations=ITERATIONS, bounds="none").normalized()
    return {**cfg.solver_options(), "tol_rel": 0.0}


FIT_FROM = 8   # the exponent's second fit: over the chains of at least this many joints (the O(n^3) regime)


def _fit(label: str, sizes: list[int], times: list[float], skipped: dict) -> dict:
    """The row of the exponents: over every timed size (None below 3 sizes), and over the sizes >= ``FIT_FROM``
    (None below 2); the sizes left out (not timed, or a diverged run's time) in ``joint_skipped`` with the reason."""
    upper = [(n, t) for n, t in zip(sizes, times) if n >= FIT_FROM]
    e = _exponent(sizes, times) if len(sizes) >= 3 else None
    e_up = _exponent(*zip(*upper)) if len(upper) >= 2 else None
    print(f"  {label}: exponent {'-' if e is None else f'{e:.2f}'} over n = {sizes}, "
          f"{'-' if e_up is None else f'{e_up:.2f}'} over n >= {FIT_FROM}", flush=True)
    return {"benchmark": f"{label} per iteration against joints", "joint_sizes": sizes, "joint_seconds": times,
            "joint_exponent": e, "joint_exponent_from": FIT_FROM, "joint_exponent_upper": e_up,
            "joint_skipped": skipped}


def scaling_rows(dgemm: float | None = None) -> list[dict]:
    """Seconds per iteration against the number of joints, R-AICO and FDDP (each its iterations' own times, its
    setup in a column of its own), with exponents, the time of each to the common cost (:func:`common_cost`) and
    the R-AICO sweeps' flops against the dgemm rate (FDDP's time beside). A run that diverged or did not descend
    keeps its row, labelled (``ended``), and stays out of the exponents and the ratios; a size a solver could not
    take is said (here and in ``joint_skipped``)."""
    from raico.planning.solvers import SOLVERS

    solvers = [("R-AICO", "raico")]
    if "fddp" in SOLVERS:
        solvers.insert(0, ("crocoddyl FDDP", "fddp"))   # first: its time goes beside R-AICO's
    per_solver: dict[str, list[dict]] = {label: [] for label, _ in solvers}
    fit: dict[str, dict[str, Any]] = {label: {"sizes": [], "times": [], "setup": [], "skipped": {}, "ended": {}} for label, _ in solvers}
    with tempfile.TemporaryDirectory() as tmp:
        files = {n: chain_problem(n, Path(tmp)) for n in CHAIN_SIZES}
        for n, f in files.items():
            details: dict[str, dict] = {}
            specs = [(solver, chain_raico_options(f) if solver == "raico" else {"iterations": ITERATIONS})
                     for _, solver in solvers]
            for (label, _), (d, why) in zip(solvers, per_iteration_details(f, specs)):
                if d is None:   # left out of the fit, and said so here and on the page
                    fit[label]["skipped"][n] = f"not timed: {why}"
                    print(f"  {label:15s} n={n:3d}  not timed: {why}", flush=True)
                    continue
                details[label] = d
                t = d["seconds"]
                if d["ended"] in ("diverged", "no descent") or t is None:   # its time is of iterations that found nothing
                    fit[label]["skipped"][n] = f"{d['ended']} ({_ms(t)} per iteration)"
                else:
                    fit[label]["sizes"].append(n)
                    fit[label]["times"].append(t)
                    fit[label]["setup"].append(d["setup_s"])
                    fit[label]["ended"][n] = d["ended"]
            for label, solver in solvers:
                if label not in details:
                    continue
                d = details[label]
                other = next((details[o] for o, _ in solvers if o != label and o in details), None)
                flops = (flop_columns(d, dgemm, f if n >= FIT_FROM else None, _relocates(chain_raico_options(f)))
                         if solver == "raico" else {})
                beside: dict = {}
                if other is not None:
                    target = common_cost(d, other)
                    beside = {"common_cost": target, "time_to_common_s": time_to(d, target)}
                    if solver == "raico":
                        beside = fddp_columns(d, other)
                        if n not in fit[label]["ended"] or other["ended"] in ("diverged", "no descent"):
                            beside.pop("ratio_to_fddp", None)   # a run that found nothing: no ratio
                row = {"benchmark": f"chain of {n} joints, analytic reach T={CHAIN_T}: one {label} iteration",
                       "median_s": d["seconds"], "samples_s": [d["seconds"]], "target_s": None, "ratio_to_target": None,
                       "setup_s": d["setup_s"], "status": d["status"], "ended": d["ended"], "start_cost": d["start_cost"],
                       "final_cost": d["final_cost"], "repeats_per_iteration": d["repeats"], **flops, **beside}
                per_solver[label].append(row)
                print(f"  {label:15s} n={n:3d}  " + _timing_note(d, other if solver == "raico" else None, row)
                      + _flop_note(flops), flush=True)
    fits = []
    for label, _ in solvers:
        g = fit[label]
        if len(g["sizes"]) >= 3 or g["skipped"]:
            fits.append({**_fit(label, g["sizes"], g["times"], g["skipped"]), "joint_ended": g["ended"],
                         "joint_setup_seconds": g["setup"]})
    rows = [r for label, _ in solvers[::-1] for r in per_solver[label]]   # R-AICO's first, as before
    return rows + fits[::-1]


def _s(x: float | None) -> str:
    """Seconds as the pages write them (ms below 1 s); "-" for none."""
    if x is None:
        return "-"
    return f"{x * 1e3:.1f} ms" if x < 1 else f"{x:.2f} s"


def _reached(x: float | None) -> str:
    return "not reached" if x is None else _s(x)


def _label(r: dict) -> str:
    name = r["benchmark"].removesuffix(": one R-AICO iteration")
    ended = r.get("ended")
    return name + (f" ({ended})" if ended in ("diverged", "no descent", "failed") else "")


def markdown_page(doc: dict) -> str:
    """The per-iteration tables (robots, then chains) from :func:`run`'s rows: R-AICO against FDDP like for like,
    the joints' exponents and the sweeps' flops."""
    rows = doc["rows"]
    raico = [r for r in rows if r["benchmark"].endswith("one R-AICO iteration")]
    lines = ["# Per-iteration time of R-AICO and FDDP on model-file robots", "",
             f"Measured by `python -m bench.model_files` ({doc['date']}; machine: {doc['machine']}). Both solvers "
             f"without hard bounds, from the start posture held, at most {ITERATIONS} iterations, one process, "
             f"medians of 3 solves; R-AICO with what `raico plan` gives a problem file (the robust schedule). "
             "Per iteration: the median of the iterations' own wall times as the solvers record them (crocoddyl's "
             "solve with no raico work between its iterations: its records are made after the solve). Setup: the "
             "time from the call to the first iteration (FDDP: crocoddyl's model built from the problem and the "
             "start's rollout; R-AICO: its first rollout, its cost and the sweeps' buffers). Common cost: the better "
             f"final cost of the two runs plus {100 * COMMON_WITHIN:g} %; the time to it is each solver's clock (its "
             "iterations' own times summed, setup not included); \"not reached\": that solver's run never got "
             "there within its iterations.", ""]
    if doc.get("note"):
        lines += [doc["note"], ""]
    if raico:
        lines += ["| problem | R-AICO per iteration | FDDP per iteration | ratio | R-AICO setup | FDDP setup | "
                  "common cost | R-AICO to it | FDDP to it | R-AICO final cost | FDDP final cost |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in raico:
            if r.get("ended") == "failed":
                lines.append(f"| {_label(r)} | {r['error']} | | | | | | | | | |")
                continue
            if "fddp_s" not in r:   # no FDDP run beside it: the reason
                lines.append(f"| {_label(r)} | {_s(r['median_s'])} | {r.get('fddp_error', '-')} | - | "
                             f"{_s(r.get('setup_s'))} | - | - | - | - | {r['final_cost']:.4g} | - |")
                continue
            ratio, common = r.get("ratio_to_fddp"), r.get("common_cost")
            to_a = "-" if common is None else _reached(r.get("time_to_common_s"))
            to_f = "-" if common is None else _reached(r.get("fddp_time_to_common_s"))
            f_end = f" ({r['fddp_ended']})" if r.get("fddp_ended") in ("diverged", "no descent") else ""
            lines.append(f"| {_label(r)} | {_s(r['median_s'])} | {_s(r['fddp_s'])} | "
                         f"{'-' if ratio is None else format(ratio, '.2f')} | {_s(r.get('setup_s'))} | "
                         f"{_s(r.get('fddp_setup_s'))} | {'-' if common is None else format(common, '.4g')} | {to_a} | "
                         f"{to_f} | {r['final_cost']:.4g} | {r['fddp_final_cost']:.4g}{f_end} |")
    fits = [r for r in rows if "joint_exponent" in r]
    if fits:
        lines += ["", "Against the number of joints (the chains above; exponent: slope of log time against log n, "
                  "over every size and over the larger chains; a run that diverged or did not lower the cost is left "
                  "out and named below):", "",
                  "| solver | joints | time per iteration | setup | exponent | exponent, larger chains |",
                  "|---|---|---|---|---|---|"]
        for r in fits:
            e, e_up = r["joint_exponent"], r.get("joint_exponent_upper")
            upper = "-" if e_up is None else f"{e_up:.2f} (n >= {r['joint_exponent_from']})"
            lines.append(f"| {r['benchmark'].removesuffix(' per iteration against joints')} | "
                         f"{', '.join(str(n) for n in r['joint_sizes'])} | "
                         f"{', '.join(_s(t) for t in r['joint_seconds'])} | "
                         f"{', '.join(_s(t) for t in r.get('joint_setup_seconds') or []) or '-'} | "
                         f"{'-' if e is None else f'{e:.2f}'} | {upper} |")
        lines += [f"\n{r['benchmark'].removesuffix(' per iteration against joints')} left out of the exponents: "
                  + "; ".join(f"n = {n}: {why}" for n, why in r["joint_skipped"].items())
                  for r in fits if r.get("joint_skipped")]
    flops = [r for r in raico if "ratio_to_dgemm" in r]
    if flops:
        lines += ["", "R-AICO's sweeps against the machine (`bench/flops.py`: the flops of the sweep an iteration "
                  "runs, from the formulas (the robust schedule: the backward messages alone), over the iteration's "
                  "own time; a one-thread dgemm measured in the same run: "
                  f"{doc.get('dgemm_gflops', float('nan')):.1f} GFLOP/s; the backward sweep alone, timed at a fixed "
                  "linearization, is the message arithmetic's own rate):", "",
                  "| problem | R-AICO per iteration | sweep flops per iteration | GFLOP/s | of dgemm | "
                  "backward sweep alone | of dgemm |", "|---|---|---|---|---|---|---|"]
        for r in flops:
            alone = (f"{r['sweep_alone_gflops']:.1f} GFLOP/s | {100 * r['sweep_alone_ratio_to_dgemm']:.0f} %"
                     if "sweep_alone_gflops" in r else "- | -")
            lines.append(f"| {_label(r)} | {_s(r['median_s'])} | {r['flops_per_iteration'] / 1e6:.1f} M | "
                         f"{r['gflops']:.2f} | {100 * r['ratio_to_dgemm']:.1f} % | {alone} |")
    return "\n".join(lines) + "\n"


PARTS = ("loads", "robots", "scaling")


def run(artifacts: Path | None = None, parts: tuple[str, ...] = PARTS, note: str = "") -> list[dict]:
    """The rows of ``parts`` (:data:`PARTS`); with ``artifacts``, also ``artifacts/bench/model_files.json`` and
    ``model_files.md`` (:func:`markdown_page`; ``note``: a sentence on how it was measured)."""
    import platform

    load0 = os.getloadavg()[0]
    rows = load_rows() if "loads" in parts else []
    for r in rows:
        print(f"{r['benchmark']:90s} median {r['median_s']:7.2f} s   target {r['target_s']:6.1f} s   "
              f"{r['ratio_to_target']:5.2f}x", flush=True)
    from bench.flops import dgemm_rate

    dgemm = dgemm_rate()
    print(f"  dgemm (one BLAS thread, this run): {dgemm:.1f} GFLOP/s", flush=True)
    rows.append({"benchmark": "dense dgemm, one BLAS thread (384 x 384)", "dgemm_gflops": dgemm})
    rows += (robot_rows(dgemm) if "robots" in parts else []) + (scaling_rows(dgemm) if "scaling" in parts else [])
    if artifacts is not None:
        from raico.pipeline.engine.atomic import write_file_atomic

        doc = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
               "machine": f"{os.cpu_count()} cpus, 1-minute load {load0:.1f} at the start and "
                          f"{os.getloadavg()[0]:.1f} at the end, Python {platform.python_version()}",
               "parts": list(parts), "note": note, "dgemm_gflops": dgemm, "rows": rows}
        out = Path(artifacts) / "bench"
        out.mkdir(parents=True, exist_ok=True)
        write_file_atomic(out / "model_files.json", json.dumps(doc, indent=2, default=float))
        write_file_atomic(out / "model_files.md", markdown_page(doc))
        print(f"wrote {out / 'model_files.json'} and model_files.md", flush=True)
    return rows


def main() -> None:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--artifacts", default="artifacts")
    ap.add_argument("--part", action="append", choices=PARTS, help="only these parts (repeatable; default: all)")
    ap.add_argument("--note", default="", help="a sentence for the page on how it was measured (e.g. a shared machine)")
    args = ap.parse_args()
    run(Path(args.artifacts), tuple(args.part or PARTS), args.note)


if __name__ == "__main__":
    main()
