"""Robots from model files: load times and per-iteration time against the number of joints.

    .venv/bin/python -m bench.model_files

- **First load** of a robot from its file in a fresh process with an empty kernel folder: the file
  repaired and parsed into Drake, the compiled tree kernels generated, compiled and checked against
  Drake, the planning problem built (its compiled task messages too). Targets: a 7-DOF arm (xArm7)
  <= 10 s, a 30-DOF humanoid (Talos on a welded sole, 32 joints) <= 60 s. **A later process** with
  the kernels on disk: <= 1 s (the load itself, the interpreter's start and imports not counted).
- **Scaling**: a serial chain of n links (n = 2 to 32, a URDF written here), a reach of its tip with
  analytic dynamics (T = 100, dt = 0.01): seconds per R-AICO iteration and per crocoddyl FDDP
  iteration (where crocoddyl translates the problem), with the exponent of a least-squares line
  through log(time) against log(n), over every size and over n >= 8 (where the dense O(n^3) algebra
  should show). Recursive dynamics and the tree's Jacobians cost O(n) to O(n^2) per step, the dense
  Riccati-like sweeps O(n^3): the exponents are reported as measured.

  The problem is one a user would write and both solvers can solve at every size. The chain hangs from
  its base, its joints alternate pitch and roll (every axis across its link; 0.2 m links of 1 kg,
  reflected motor inertia 0.01 kg m^2), and it starts at rest in a zigzag, every link within 0.3 rad of
  hanging straight (:func:`chain_start`): that posture, held by the torques that hold it, is a stable
  equilibrium of the semi-implicit Euler step at dt = 0.01 (spectral radius 1 to rounding at every size:
  no mode grows), and its zero-torque swing stays below 11 rad/s. An upright chain with twist joints
  about its links (what this bench wrote before) is not: its held start grows by 1.9x per step at 32
  joints, its passive fall overflows in the zero-torque rollout from 16 joints on (at 32 joints even
  with dt = 0.002), and both solvers diverged there. The costs are crocoddyl's reach formulation (the
  Kinova example): the tip 5 cm out and 5 cm up from its start at T (weight 1e4; FDDP's 4 iterations put
  the tip within 0.1 mm of it from 4 joints on, while the 2-joint chain's tip moves on a surface and
  ends at its nearest point), the state kept near the start posture at rest (1e-3 per step) and the
  torques near the ones that hold the chain (1e-3; toward zero instead, the cheapest plan lets a long
  chain swing, and FDDP's tip ends farther from the target than it started from 8 joints on). Both
  solvers start from the start posture held (x0 at every step, zero controls), without hard bounds (plain
  FDDP keeps none); R-AICO runs as ``raico plan`` runs a problem file (:func:`chain_raico_options`: its robust
  schedule; the thesis's fixed alpha = 1 diverges at 32 joints in its first iteration). A run's row says
  how it ended (``ended``): one that diverged or did not lower the cost keeps its time, labelled, and
  stays out of the exponents and the ratio to FDDP.

- **Robots** (the Kinova, UR5 and xArm7 problem files, T = 100): seconds per R-AICO and per FDDP
  iteration and their ratio.
- **Flops**: beside every R-AICO row, the sweep's flops per iteration from the formulas of
  :mod:`bench.flops`, the achieved GFLOP/s and its ratio to a one-thread dgemm measured in the same
  run (a row of its own).

Not a test: nothing here fails on a slow machine.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

CHAIN_SIZES = (2, 4, 8, 16, 32)
CHAIN_T = 100
ITERATIONS = 4

_LOAD = textwrap.dedent("""
    import json, sys, time
    t0 = time.perf_counter()
    from stages.plan.stage import PlanConfig, build_problem
    t_import = time.perf_counter()
    cfg = PlanConfig(problem=sys.argv[1], iterations=1).normalized()
    cfg.validate()
    build_problem(cfg)
    from plants.fast_analytic import make_fast_or_exact
    from stages.plan.stage import robot_and_task
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
    from plants.model_file import example_robot_data

    if example_robot_data() is None:
        return []
    root = Path(__file__).resolve().parents[1]
    cases = [("xArm7 (7 joints)", root / "problems/examples/xarm7_reach.toml", 10.0),
             ("Talos on its right sole (32 joints)", root / "problems/crocoddyl/talos_taichi.toml", 60.0)]
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


def _per_iteration(problem_file: Path, solver: str, options: dict, reps: int = 3) -> tuple[float | None, str]:
    """(median seconds per iteration, "") or (None, why the solver could not take the problem)."""
    detail, why = _per_iteration_detail(problem_file, solver, options, reps)
    return (None if detail is None else detail["seconds"]), why


def _per_iteration_detail(problem_file: Path, solver: str, options: dict, reps: int = 3) -> tuple[dict | None, str]:
    """Median seconds per iteration over ``reps`` solves (without hard bounds, as FDDP: like for like; the solve's
    time over its iterations, its setup included: crocoddyl's model built from the problem, R-AICO's first
    rollout and last beliefs), the median of the median run's iterations' own wall times (``iteration_s``,
    as the solvers record them: no setup), the repeats of a step per iteration (R-AICO's relinearizations within the sweeps; 0 for the others), how the
    median run ended (``status``; ``ended``: :func:`_ended`), its start's and its last iteration's cost and
    the problem's sizes, and ""; or (None, why the solver could not take the problem)."""
    from planning.solvers import solve
    from stages.plan.stage import PlanConfig, build_problem

    times, repeats, runs = [], [], []
    for _ in range(reps):
        _, _, problem, _, _ = build_problem(PlanConfig(problem=str(problem_file), bounds="none").normalized())
        try:
            t0 = time.perf_counter()
            res = solve(problem, solver, options)
        except Exception as e:  # noqa: BLE001 - a solver that cannot take the problem: no time, said why
            return None, f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}".rstrip(": ")
        times.append((time.perf_counter() - t0) / max(1, res.iterations))
        repeats.append(sum(getattr(h, "repeats", 0) or 0 for h in res.history) / max(1, res.iterations))
        runs.append(res)
    i = int(np.argsort(times)[len(times) // 2])   # the median run's own repeats and ending
    res = runs[i]
    status = str(getattr(res.status, "value", res.status))
    final = float(res.history[-1].cost) if res.history else float("inf")
    own = [h.time_s for h in res.history]
    return {"seconds": times[i], "iteration_s": float(np.median(own)) if own else None, "repeats": repeats[i],
            "n_x": problem.n_x, "n_u": problem.n_u, "T": problem.T, "status": status,
            "start_cost": float(res.initial_cost), "final_cost": final,
            "ended": _ended(status, float(res.initial_cost), final)}, ""


def _ended(status: str, start_cost: float, final_cost: float) -> str:
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


ROBOTS = (("Kinova reach (crocoddyl)", "problems/crocoddyl/kinova_reach.toml"),
          ("UR5 reach", "problems/examples/ur5_reach.toml"), ("xArm7 reach", "problems/examples/xarm7_reach.toml"))


def _flops(detail: dict, dgemm: float | None, problem_file: Path | None = None) -> dict:
    """The sweep's flop columns of an R-AICO measurement (bench.flops), none without a dgemm rate; with
    ``problem_file`` also the backward sweep timed alone (``sweep_alone_*``: the message arithmetic's own rate)."""
    if dgemm is None:
        return {}
    from bench.flops import backward_sweep_rate, flop_fields

    out = flop_fields(detail["n_x"], detail["n_u"], detail["T"], detail["seconds"], dgemm, detail["repeats"])
    if problem_file is not None:
        from stages.plan.stage import PlanConfig, build_problem

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


def robot_rows(dgemm: float | None = None) -> list[dict]:
    """R-AICO and FDDP seconds per iteration on the Kinova, UR5 and xArm7 problems (T = 100), their
    ratio (over the solve, and over the iterations' own times), and R-AICO's sweep flops against the dgemm
    rate. R-AICO runs with what ``raico plan`` gives the problem file (:func:`chain_raico_options`)."""
    from planning.solvers import SOLVERS
    from plants.model_file import example_robot_data

    if example_robot_data() is None:
        return []
    root = Path(__file__).resolve().parents[1]
    rows = []
    for label, rel in ROBOTS:
        a = _per_iteration_detail(root / rel, "raico", chain_raico_options(root / rel))[0]
        f = _per_iteration_detail(root / rel, "fddp", {"iterations": ITERATIONS})[0] if "fddp" in SOLVERS else None
        if a is None:
            continue
        row = {"benchmark": f"{label}: one R-AICO iteration", "median_s": a["seconds"], "samples_s": [a["seconds"]],
               "target_s": None, "ratio_to_target": None, "repeats_per_iteration": a["repeats"], "status": a["status"],
               "ended": a["ended"], "iteration_s": a["iteration_s"], **_flops(a, dgemm, root / rel)}
        if f is not None:
            row.update(fddp_s=f["seconds"], ratio_to_fddp=a["seconds"] / f["seconds"], fddp_iteration_s=f["iteration_s"])
            if a["iteration_s"] and f["iteration_s"]:
                row["ratio_to_fddp_own"] = a["iteration_s"] / f["iteration_s"]
        rows.append(row)
        print(f"  {label:28s} R-AICO {a['seconds'] * 1e3:7.2f} ms"
              + (f"  FDDP {f['seconds'] * 1e3:7.2f} ms  ratio {a['seconds'] / f['seconds']:5.2f}" if f else "")
              + _flop_note(row), flush=True)
    return rows


def chain_raico_options(problem_file: Path) -> dict:
    """R-AICO's options on a problem file (a chain, a robot): the ones ``raico plan`` gives it (its robust
    schedule, alpha 1), every iteration run (``tol_rel = 0``)."""
    from stages.plan.stage import PlanConfig

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
    """Seconds per iteration against the number of joints, R-AICO and FDDP, with exponents (and the
    R-AICO sweeps' flops against the dgemm rate, FDDP's time beside). A run that diverged or did not descend
    keeps its row, labelled (``ended``), and stays out of the exponents and the ratios."""
    from planning.solvers import SOLVERS

    per_solver: dict[str, list[dict]] = {}
    fddp: dict[int, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        files = {n: chain_problem(n, Path(tmp)) for n in CHAIN_SIZES}
        solvers = [("R-AICO", "raico")]
        if "fddp" in SOLVERS:
            solvers.insert(0, ("crocoddyl FDDP", "fddp"))   # first: its time goes beside R-AICO's
        fits = []
        for label, solver in solvers:
            sizes, times, own, skipped, ended = [], [], [], {}, {}
            rows = per_solver.setdefault(label, [])
            for n, f in files.items():
                options = chain_raico_options(f) if solver == "raico" else {"iterations": ITERATIONS}
                d, why = _per_iteration_detail(f, solver, options)
                if d is None:   # left out of the fit, and said so here and on the page
                    skipped[n] = f"not timed: {why}"
                    print(f"  {label:15s} n={n:3d}  not timed: {why}", flush=True)
                    continue
                t = d["seconds"]
                if d["ended"] in ("diverged", "no descent"):   # its time is of iterations that found nothing
                    skipped[n] = f"{d['ended']} ({t * 1e3:.1f} ms per iteration)"
                else:
                    sizes.append(n)
                    times.append(t)
                    own.append(d["iteration_s"])
                    ended[n] = d["ended"]
                flops = _flops(d, dgemm, f if n >= FIT_FROM else None) if solver == "raico" else {}
                beside = {}
                if solver == "fddp":
                    fddp[n] = d
                elif n in fddp and n in ended and fddp[n]["ended"] not in ("diverged", "no descent"):
                    beside = {"fddp_s": fddp[n]["seconds"], "ratio_to_fddp": t / fddp[n]["seconds"],
                              "fddp_iteration_s": fddp[n]["iteration_s"]}
                    if d["iteration_s"] and fddp[n]["iteration_s"]:
                        beside["ratio_to_fddp_own"] = d["iteration_s"] / fddp[n]["iteration_s"]
                rows.append({"benchmark": f"chain of {n} joints, analytic reach T={CHAIN_T}: one {label} iteration",
                             "median_s": t, "samples_s": [t], "target_s": None, "ratio_to_target": None,
                             "status": d["status"], "ended": d["ended"], "start_cost": d["start_cost"],
                             "final_cost": d["final_cost"], "repeats_per_iteration": d["repeats"],
                             "iteration_s": d["iteration_s"], **flops, **beside})
                own_ms = "-" if d["iteration_s"] is None else f"{d['iteration_s'] * 1e3:.2f}"
                print(f"  {label:15s} n={n:3d}  {t * 1e3:8.2f} ms/iteration (the iterations' own: {own_ms} ms)  "
                      f"({d['ended']}: cost {d['start_cost']:.4g}"
                      f" -> {d['final_cost']:.4g}, {d['repeats']:.0f} repeats/iteration)" + _flop_note(flops),
                      flush=True)
            if len(sizes) >= 3 or skipped:
                fits.append({**_fit(label, sizes, times, skipped), "joint_ended": ended, "joint_iteration_seconds": own})
    rows = [r for label, _ in solvers[::-1] for r in per_solver.get(label, [])]   # R-AICO's first, as before
    return rows + fits[::-1]


def run() -> list[dict]:
    rows = load_rows()
    for r in rows:
        print(f"{r['benchmark']:90s} median {r['median_s']:7.2f} s   target {r['target_s']:6.1f} s   "
              f"{r['ratio_to_target']:5.2f}x", flush=True)
    from bench.flops import dgemm_rate

    dgemm = dgemm_rate()
    print(f"  dgemm (one BLAS thread, this run): {dgemm:.1f} GFLOP/s", flush=True)
    rows.append({"benchmark": "dense dgemm, one BLAS thread (384 x 384)", "dgemm_gflops": dgemm})
    return rows + robot_rows(dgemm) + scaling_rows(dgemm)


if __name__ == "__main__":
    run()
