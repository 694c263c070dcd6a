"""A solver suite as files, judged by performance profiles: ``raico bench suite``.

The suite is a list file (``raico/problems/suite/suite.toml``: its budgets, the solvers as labels and plan
options, problem files named with their own options) and every other problem file of its folder; the
list file's keys: docs/suite.md, "The list file".

Every solver runs on every problem as an ordinary cached plan (seed 0, the problem's start posture,
q0-std 0) through the experiment machinery (:mod:`raico.pipeline.experiments.expfile`): the runs table is
``artifacts/exp/<name>/runs.csv`` (``raico exp show suite``), a second call computes nothing. Per run:
the final cost at the iteration and time budgets, status, iterations, wall time, the time to within
``within`` of the best final cost, and the plan's largest excess over the joint ranges, the model file's
velocity limits and the effort limits.

Every plan is also executed in Drake (``raico execute`` at its defaults, an ordinary cached run): its
status and execute's one judgement of the task (:func:`raico.stages.evaluate.metrics.executed_task`) are
columns. With ``reference = true`` the direct-transcription reference
(:mod:`raico.pipeline.experiments.transcription`, SNOPT) joins the best feasible cost known.

Across problems, Dolan and Moré's performance profiles (Math. Program. 91, 2002): ``r[p, s] = m[p, s]
/ min_s m[p, s]`` and ``rho_s(tau) = |{p : r[p, s] <= tau}| / n_problems`` for the cost, time, inside
and executed measures (docs/suite.md). A cell without a value counts as not solved; a problem no
solver solved stays in the denominator.

Bad input does not stop the suite: a problem file that does not exist, a budget of 0, a solver
whose options do not make a plan, a run that raises (crocoddyl cannot express a robot welded on a
frame other than its root) are each one line on stderr, and the table says why the cell is empty.
"""

from __future__ import annotations

import math
import os
import platform
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from raico.pipeline.errors import BadInput
from raico.pipeline.experiments.expfile import read_toml

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_FILE = ROOT / "problems" / "suite" / "suite.toml"
TOP_KEYS = ("name", "description", "iterations", "time_budget_s", "within", "reference", "reference_time_s",
            "reference_total_s", "solver", "problem")
SOLVER_KEYS = ("label", "needs", "optional", "rollout")   # a solver entry's keys that are not plan options
PROBLEM_KEYS = ("file", "label", "dynamics", "start", "q0_std", "iterations", "time_budget_s")
STARTS = ("held", "rollout", "quasi-static")
STAGES = ("plan", "execute")   # every plan of the suite is executed in Drake (execute's defaults)
TAUS = (1.0, 1.01, 1.1, 1.5, 2.0, 10.0)   # the profiles' table columns


# ----------------------------------------------------------------------------- the list file
@dataclass
class SolverEntry:
    label: str
    options: dict[str, Any]
    rollout: str | None = None   # the solver's name from the zero-control rollout
    optional: bool = False


@dataclass
class ProblemEntry:
    label: str
    file: Path
    dynamics: str = ""
    start: str = "held"
    q0_std: float | None = None   # rad: the start posture's spread (seed 0); None: the file's posture exactly
    iterations: int = 40
    time_budget_s: float = 20.0
    reason: str = ""              # why none of its cells runs ("" : they run)


@dataclass
class Suite:
    name: str
    description: str
    path: Path
    solvers: list[SolverEntry]
    problems: list[ProblemEntry]
    within: float = 0.01
    notes: list[str] = field(default_factory=list)   # the lines said while loading (left-out entries)
    reference: bool = False   # run the direct-transcription reference on the problems small enough
    reference_time_s: float = 300.0   # its time limit per problem (s)
    reference_total_s: float = math.inf   # the references computed in one call stop after this (s, wall)


def _budget(value: Any, what: str, integer: bool) -> float:
    ok = (isinstance(value, int) if integer else isinstance(value, (int, float))) and not isinstance(value, bool)
    if not ok or value < 0 or not math.isfinite(value):
        raise BadInput(f"{what} must be {'an integer' if integer else 'a number'} >= 0, got {value!r}")
    return value


def _problem_label(file: Path) -> str:
    try:
        return str(tomllib.loads(file.read_text()).get("name") or file.stem)
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError):
        return file.stem


def load(path: str | Path | None = None) -> Suite:
    """The suite of list file ``path`` (default ``raico/problems/suite/suite.toml``): its solvers, and its
    problems (the entries, then every other ``*.toml`` of the folder not named by one). A problem
    file that does not exist or a budget of 0 is kept with its ``reason`` (its cells stay empty);
    a malformed list file is :class:`BadInput`."""
    path = Path(path or DEFAULT_FILE).resolve()
    doc = read_toml(path, "suite file")
    unknown = [k for k in doc if k not in TOP_KEYS]
    if unknown:
        raise BadInput(f"{path}: unknown key '{unknown[0]}': valid keys are {', '.join(TOP_KEYS)}")
    iterations = int(_budget(doc.get("iterations", 40), f"{path.name}: iterations", True))   # an integer, checked
    budget = _budget(doc.get("time_budget_s", 20.0), f"{path.name}: time_budget_s", False)
    within = _budget(doc.get("within", 0.01), f"{path.name}: within", False)
    suite = Suite(str(doc.get("name", path.stem)), str(doc.get("description", "")), path, [], [], float(within))
    if not isinstance(doc.get("reference", False), bool):
        raise BadInput(f"{path}: reference must be true or false, got {doc['reference']!r}")
    suite.reference = bool(doc.get("reference", False))
    suite.reference_time_s = float(_budget(doc.get("reference_time_s", REFERENCE_TIME_S),
                                           f"{path.name}: reference_time_s", False))
    if "reference_total_s" in doc:   # absent: no limit
        suite.reference_total_s = float(_budget(doc["reference_total_s"], f"{path.name}: reference_total_s", False))
    suite.solvers = _solvers(path, doc.get("solver", []), suite.notes)
    entries = doc.get("problem", [])
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise BadInput(f"{path}: [[problem]] entries must be tables")
    named = set()
    for e in entries:
        bad = [k for k in e if k not in PROBLEM_KEYS]
        if bad or not isinstance(e.get("file"), str):
            raise BadInput(f"{path}: problem {e.get('label') or e.get('file')!r}: "
                           + (f"unknown key '{bad[0]}': valid keys are {', '.join(PROBLEM_KEYS)}" if bad
                              else "give its file = \"PATH\""))
        file = (path.parent / e["file"]).resolve()
        named.add(file)
        suite.problems.append(_problem(path, e, file, iterations, budget))
    for file in sorted(path.parent.glob("*.toml")):
        if file.resolve() != path and file.resolve() not in named:
            suite.problems.append(_problem(path, {}, file.resolve(), iterations, budget))
    labels = [p.label for p in suite.problems]
    twice = sorted({lb for lb in labels if labels.count(lb) > 1})
    if twice:
        raise BadInput(f"{path}: two problems are labelled '{twice[0]}': give one a label = \"...\"")
    return suite


def _solvers(path: Path, entries: Any, notes: list[str]) -> list[SolverEntry]:
    from raico.pipeline.experiments.expfile import available

    if not isinstance(entries, list) or not entries or not all(isinstance(e, dict) for e in entries):
        raise BadInput(f"{path}: give at least one [[solver]] table")
    out: list[SolverEntry] = []
    for e in entries:
        label = e.get("label")
        if not isinstance(label, str) or not label or any(s.label == label for s in out):
            raise BadInput(f"{path}: every [[solver]] needs a unique label (got {label!r})")
        if "needs" in e and not available(str(e["needs"])):
            notes.append(f"suite: solver '{label}' left out: it needs {e['needs']}, which is not installed")
            continue
        opts = {k: v for k, v in e.items() if k not in SOLVER_KEYS}
        if "solver" not in opts:
            raise BadInput(f"{path}: solver '{label}': give its solver = \"NAME\"")
        if e.get("optional"):
            why = _solver_refusal(opts)
            if why:
                notes.append(f"suite: solver '{label}' left out (optional): {why}")
                continue
        out.append(SolverEntry(label, opts, e.get("rollout"), bool(e.get("optional", False))))
    return out


def _solver_refusal(opts: dict) -> str:
    """Why a solver's options do not make a plan on any problem ("" where they do), checked on a
    built-in task."""
    from raico.pipeline.experiments.expfile import stage_config

    try:
        stage_config("plan", {"plant": "arm5", "task": "reach", **opts})
    except BadInput as e:
        return str(e).removeprefix("plan: ")
    return ""


def _problem(path: Path, e: dict, file: Path, iterations: int, budget: float) -> ProblemEntry:
    label = e.get("label") or (_problem_label(file) if file.exists() else Path(e.get("file", file)).stem)
    p = ProblemEntry(str(label), file, str(e.get("dynamics", "")), str(e.get("start", "held")), e.get("q0_std"),
                     e.get("iterations", iterations), e.get("time_budget_s", budget))
    try:
        _budget(p.iterations, f"problem '{p.label}': iterations", True)
        _budget(p.time_budget_s, f"problem '{p.label}': time_budget_s", False)
    except BadInput as err:
        p.reason = str(err)
        return p
    if not file.exists():
        p.reason = f"no problem file {e.get('file', file)} (looked for {file})"
    elif p.iterations == 0 or p.time_budget_s == 0:
        p.reason = f"a budget of 0 ({'iterations' if p.iterations == 0 else 'time_budget_s'} = 0): nothing to run"
    elif p.start not in STARTS:
        p.reason = f"start '{p.start}' is not one of {', '.join(STARTS)}"
    return p


def options(problem: ProblemEntry, solver: SolverEntry) -> dict[str, Any]:
    """The plan options of one cell (the problem's start and budgets on the solver's options)."""
    opts = {"problem": str(problem.file), **solver.options, "iterations": int(problem.iterations)}
    if problem.dynamics:
        opts["dynamics"] = problem.dynamics
    if problem.q0_std is not None:
        opts["q0_std"] = problem.q0_std
    if problem.start == "rollout" and solver.rollout:
        opts["solver"] = solver.rollout
    elif problem.start != "held":
        opts["start"] = problem.start
    return opts


# ----------------------------------------------------------------------------- running
@dataclass
class Cell:
    problem: str
    solver: str
    options: dict[str, Any] | None = None
    reason: str = ""              # why it did not run or has no result
    row: dict[str, Any] = field(default_factory=dict)   # its runs-table row (raico.pipeline.experiments.expfile.table_row)


def cells(suite: Suite, say: Callable[[str], None]) -> list[Cell]:
    """Every problem x solver cell, the options of those that can run checked by the plan stage's
    config; each that cannot is one line through ``say`` and keeps its reason."""
    from raico.pipeline.experiments.expfile import stage_config

    out = []
    for p in suite.problems:
        if p.reason:
            say(f"suite: problem '{p.label}': {p.reason}; its cells stay empty")
        for s in suite.solvers:
            cell = Cell(p.label, s.label)
            if p.reason:
                cell.reason = p.reason
            else:
                opts = options(p, s)
                try:
                    stage_config("plan", opts)
                    cell.options = opts
                except BadInput as e:
                    cell.reason = str(e).removeprefix("plan: ")
                    say(f"suite: {p.label} x {s.label}: {cell.reason}")
            out.append(cell)
    return out


def experiment(suite: Suite, runnable: list[Cell]):
    """The suite's runs as an experiment (one point per runnable cell, seed 0): its runs are the
    plans ``raico plan --problem FILE ...`` would make, its table ``raico exp show <name>``'s."""
    from raico.pipeline.experiments.expfile import Experiment, Variant

    points = [{"label": f"{c.problem} | {c.solver}", **c.options, "seeds": ()} for c in runnable]
    exp = Experiment(suite.name, suite.description, STAGES, (0,), {"plan": {}, "execute": {}}, {}, {}, points,
                     suite.path)
    # the table's option columns: the suite's labels (the problem's canonical content would fill a screen)
    exp.variants = [Variant(f"{c.problem} | {c.solver}", {"plan": dict(c.options), "execute": {}},
                            {"problem": c.problem, "solver": c.solver}) for c in runnable]
    return exp


def run(cache, suite: Suite, executor, say: Callable[[str], None],
        progress: Callable[[Any], None] | None = None) -> list[Cell]:
    """Every cell of ``suite``: the runnable ones through the cache (``executor``), the runs table
    written; a run that raised keeps its error as the cell's reason (one line through ``say``)."""
    from raico.pipeline.experiments import expfile

    all_cells = cells(suite, say)
    runnable = [c for c in all_cells if c.options is not None]
    if runnable:
        exp = experiment(suite, runnable)
        rows = expfile.run(cache, exp, executor, record=False, progress=progress)
        for c, row in zip(runnable, rows):
            c.row = row
            if row["status"] == "error" and not row.get("plan.key"):   # the plan raised: the cell is empty
                c.reason = row["error"].removeprefix("plan: ")
                say(f"suite: {c.problem} x {c.solver}: {c.reason}")
            elif row["status"] == "error":                             # the execution raised: said, the plan kept
                say(f"suite: {c.problem} x {c.solver}: {row['error']}")
    return all_cells


# ----------------------------------------------------------------------------- measuring
def cost_at_budget(costs: np.ndarray, elapsed: np.ndarray, final: float | None, budget: float) -> float | None:
    """The run's cost at the time budget (s): ``final`` (the plan's) if its last iteration finished
    within it, else the cost of the last iteration that did (``None``: none did, or diverged)."""
    if final is None or not math.isfinite(final):
        return None
    if elapsed.size == 0 or elapsed[-1] <= budget:
        return float(final)
    done = np.nonzero(elapsed <= budget)[0]
    if not done.size or not math.isfinite(costs[done[-1]]):
        return None
    return float(costs[done[-1]])


def time_to(costs: np.ndarray, elapsed: np.ndarray, target: float, budget: float = math.inf) -> float | None:
    """Wall time (s) at which the run's cost first came to ``target`` or below within the budget."""
    hit = np.nonzero(np.isfinite(costs) & (costs <= target) & (elapsed <= budget))[0]
    return float(elapsed[hit[0]]) if hit.size else None


def target_of(best: float, within: float) -> float:
    """The cost within ``within`` (relative) of ``best``."""
    return best + within * abs(best)


def limit_violations(robot, X: np.ndarray, U: np.ndarray, torques: np.ndarray | None) -> dict[str, float | None]:
    """``joint_range``: the largest excess of a planned joint position over the model's range (rad or
    m, 0 inside); ``velocity``: the largest excess of a planned joint speed over the model file's velocity
    limit (rad/s or m/s, steps 1..T: the start is given; 0 inside or without limits); ``effort``: the largest
    excess of a joint torque over its effort limit (N m). ``torques (T, n)``: the plan's torques (``U`` for
    torque-controlled dynamics)."""
    n = robot.n_q
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(U))):
        return {"joint_range": None, "velocity": None, "effort": None}
    Q = X[:, :n]
    excess = np.maximum(np.maximum(Q - robot.upper, robot.lower - Q), 0.0)
    vmax = np.full(n, np.inf) if getattr(robot, "velocity", None) is None else np.asarray(robot.velocity, float)
    V = X[1:, n:2 * n]
    speed = np.maximum(np.abs(V) - vmax, 0.0) if V.size else np.zeros(1)
    tau = U if torques is None else torques
    effort = np.maximum(np.abs(tau) - np.asarray(robot.effort, float), 0.0) if tau is not None else None
    return {"joint_range": float(excess.max()), "velocity": float(speed.max()),
            "effort": None if effort is None or not np.all(np.isfinite(tau)) else float(effort.max())}


def iterate_range_excess(X_iterations: np.ndarray, t_iterations: np.ndarray, robot) -> np.ndarray:
    """Per iterate (row 0 the initial trajectory, row ``i`` iteration ``i``'s), the largest excess of a joint
    position over the model's range (rad, or m) at the steps the plan keeps of its iterates
    (``X_iterations (I+1, K, n_x)`` at steps ``t_iterations (K,)``: every n-th step and the via-points;
    the start, step 0, left out: no plan changes it); NaN for an iterate not recorded (diverged)."""
    n = robot.n_q
    keep = np.asarray(t_iterations) > 0
    Q = np.asarray(X_iterations, float)[:, keep, :n]
    with np.errstate(invalid="ignore"):
        excess = np.maximum(np.maximum(Q - robot.upper, robot.lower - Q), 0.0)
        out = excess.reshape(len(Q), -1).max(axis=1) if Q.size else np.zeros(len(Q))
    recorded = np.all(np.isfinite(Q.reshape(len(Q), -1)), axis=1) if Q.size else np.ones(len(Q), bool)
    return np.where(recorded, out, np.nan)


def _torques(problem_cache: dict, options: dict, X: np.ndarray, U: np.ndarray):
    """The robot of a cell and its plan's torques (computed torque for pseudo-dynamics)."""
    from raico.plants.dynamics_registry import make_dynamics
    from raico.stages.plan.stage import PlanConfig, robot_and_task

    cfg = PlanConfig(**{k: v for k, v in options.items()}).normalized()
    key = (cfg.problem, cfg.dynamics)
    if key not in problem_cache:
        robot, task = robot_and_task(cfg)
        pseudo = cfg.dynamics.startswith("pseudo")
        problem_cache[key] = (robot, make_dynamics("analytic", robot, task.dt) if pseudo else None)
    robot, analytic = problem_cache[key]
    if analytic is None or not np.all(np.isfinite(X)):
        return robot, None
    n = robot.n_q
    tau = np.array([analytic.inverse_dynamics(x[:n], x[n:], u) for x, u in zip(X[:-1], U)])
    return robot, tau


def execution_columns(row: dict[str, Any]) -> dict[str, Any]:
    """The execution's columns of a runs-table row: ``execution`` (execute's status, ``error`` where it
    raised, ``None`` not run), ``task_achieved`` (execute's one judgement,
    :func:`raico.stages.evaluate.metrics.executed_task`: every via-point term within its tolerance and the status
    ``ok``; ``None`` without task terms), ``task_note`` (:func:`raico.stages.evaluate.metrics.task_note`) and
    ``execute_key``."""
    from raico.stages.evaluate.metrics import executed_task, task_note

    status = row.get("execute.status")
    out: dict[str, Any] = {"execution": None if status in (None, "not run") else str(status),
                           "task_achieved": None, "task_note": None, "execute_key": row.get("execute.key")}
    task = {k.removeprefix("execute.task."): v for k, v in row.items() if k.startswith("execute.task.")}
    if out["execute_key"] and {"achieved", "worst", "error", "tol", "unit", "kind"} <= set(task):
        verdict = executed_task(task, str(status))
        if verdict is not None:
            out["task_achieved"], out["task_note"] = bool(verdict["achieved"]), task_note(verdict)
    return out


def executed_ok(record: dict) -> bool:
    """Whether a run's plan, executed in Drake, ended ``ok`` and achieved its task (execute's judgement);
    a run without an execution or without task terms is not."""
    return record.get("execution") == "ok" and record.get("task_achieved") is True


def measure(cache, suite: Suite, all_cells: list[Cell]) -> list[dict[str, Any]]:
    """One record per cell: the numbers of the module docstring (``None`` where there is none, with
    ``reason``), the best cost and time-to-target per problem filled in."""
    budgets = {p.label: p.time_budget_s for p in suite.problems}
    robots: dict = {}
    records = []
    for c in all_cells:
        rec: dict[str, Any] = {"problem": c.problem, "solver": c.solver, "status": "not run", "iterations": None,
                               "final_cost": None, "wall_time_s": None, "time_to_target_s": None,
                               "cost_ratio": None, "joint_range_excess": None, "velocity_excess": None,
                               "effort_excess": None,
                               "key": None, "reason": c.reason, "over_time_budget": False, "cached": False,
                               "inside_limits": None, "execution": None, "task_achieved": None, "task_note": None,
                               "execute_key": None}
        row = c.row
        if row and row.get("plan.key"):
            rec.update(key=row["plan.key"], status=row.get("plan.status"), iterations=row.get("plan.iterations"),
                       cached=bool(row.get("plan.cached")),
                       wall_time_s=row.get("plan.wall_time_s"))
            with np.load(cache.root / "plan" / row["plan.key"] / "plan.npz", allow_pickle=False) as f:
                costs, elapsed = np.asarray(f["costs"], float), np.asarray(f["elapsed"], float)
                X, U = np.asarray(f["X"], float), np.asarray(f["U"], float)
                iterates = ((np.asarray(f["X_iterations"], float), np.asarray(f["t_iterations"]))
                            if {"X_iterations", "t_iterations"} <= set(f.files) else None)
            final = None if rec["status"] == "diverged" else row.get("plan.final_cost")
            rec["final_cost"] = cost_at_budget(costs, elapsed, final, budgets[c.problem])
            rec["over_time_budget"] = bool(elapsed.size and elapsed[-1] > budgets[c.problem])
            rec["_curve"] = (costs, elapsed)
            robot, tau = _torques(robots, c.options, X, U)
            v = limit_violations(robot, X, U, tau)
            rec["joint_range_excess"], rec["effort_excess"] = v["joint_range"], v["effort"]
            rec["velocity_excess"] = v["velocity"]
            rec["inside_limits"] = inside_limits(rec)
            rec["iteration_costs"] = [float(c) if math.isfinite(c) else None for c in costs]
            rec["iteration_range_excess"] = (None if iterates is None else
                                             [None if not math.isfinite(v) else float(v)
                                              for v in iterate_range_excess(*iterates, robot)])
            rec.update(execution_columns(row))
            if rec["final_cost"] is None and not rec["reason"]:
                rec["reason"] = "diverged" if rec["status"] == "diverged" else "no finite cost within the budget"
        elif row and row.get("status") == "error":
            rec["status"] = "error"
        records.append(rec)
    for p in suite.problems:
        mine = [r for r in records if r["problem"] == p.label]
        finals = [r["final_cost"] for r in mine if r["final_cost"] is not None]
        best = min(finals) if finals else None
        for r in mine:
            r["best_cost"] = best
            if best is not None and r["final_cost"] is not None:
                r["cost_ratio"] = _ratio(r["final_cost"], best)
            curve = r.pop("_curve", None)
            if best is not None and curve is not None:
                costs, elapsed = curve
                r["time_to_target_s"] = time_to(costs, elapsed, target_of(best, suite.within), p.time_budget_s)
    return records


# ----------------------------------------------------------------------------- the reference
REFERENCE_JOINTS = 7    # the direct-transcription reference runs on problems of at most this many joints ...
REFERENCE_STEPS = 100   # ... and steps
REFERENCE_SOLVER = "snopt"
REFERENCE_TIME_S = 300.0
REFERENCE_ITERATIONS = 300   # SNOPT's major iterations: its bound on the reference's time (its own time limit
                             # counts CPU seconds and is not kept between major iterations)


def reference_record(cache, suite: Suite, problem: ProblemEntry, records: list[dict],
                     say: Callable[[str], None], solver: str = REFERENCE_SOLVER,
                     cached_only: bool = False) -> dict[str, Any] | None:
    """The direct-transcription reference on one problem (:mod:`raico.pipeline.experiments.transcription`): the
    problem with its hard bounds (the robot's ranges, and effort limits for torques), warm-started from the
    cheapest plan inside the limits (else the cheapest plan), by ``solver``. Its record (cost, status,
    feasible, dynamics defect, bounds' excess, time, warm start) is kept under ``<cache>/reference/`` by
    :func:`raico.pipeline.experiments.transcription.cache_key` (the warm start's plan key, the solver's iteration
    limit, the problem's start and hard bounds, velocity limits included), so a second call solves nothing;
    ``None`` where the problem is too large or no plan of it has a finite cost, or, with ``cached_only`` (the
    call's ``reference_total_s`` is spent), where it is not cached (said through ``say``: a later call goes on)."""
    import json

    from raico.pipeline.engine.atomic import write_file_atomic
    from raico.pipeline.experiments.transcription import cache_key, refusal, solve
    from raico.stages.plan.stage import PlanConfig, build_problem

    mine = [r for r in records if r["problem"] == problem.label and r["key"] and r["final_cost"] is not None]
    if not mine:
        return None
    warm = min(mine, key=lambda r: (not r.get("inside_limits"), r["final_cost"]))
    entry = next(s for s in suite.solvers if s.label == warm["solver"])
    cfg = PlanConfig(**{**options(problem, entry), "bounds": "hard"})
    _, _, pb, _, _ = build_problem(cfg)
    path = cache.root / "reference" / f"{cache_key(pb, warm['key'], solver, REFERENCE_ITERATIONS)}.json"
    if path.exists():
        return json.loads(path.read_text())
    why = refusal(pb, REFERENCE_JOINTS, REFERENCE_STEPS)
    if why:
        say(f"suite: {problem.label}: no transcription reference ({why})")
        return None
    if cached_only:
        say(f"suite: {problem.label}: no transcription reference in this call (reference_total_s = "
            f"{suite.reference_total_s:g} s spent; the next call goes on)")
        return None
    with np.load(cache.root / "plan" / warm["key"] / "plan.npz", allow_pickle=False) as f:
        X, U = np.asarray(f["X"], float), np.asarray(f["U"], float)
    out = solve(pb, X, U, solver=solver, max_iterations=REFERENCE_ITERATIONS, time_limit_s=suite.reference_time_s)
    rec = {**out.record(), "warm_start": f"{warm['solver']} ({_f(warm['final_cost'])})", "warm_key": warm["key"]}
    path.parent.mkdir(parents=True, exist_ok=True)
    from raico.pipeline.engine.runner import finite_json

    write_file_atomic(path, json.dumps(finite_json(rec)).encode())
    say(f"suite: {problem.label}: transcription reference ({solver}) {out.status}, cost {_f(rec['cost'])}, "
        f"{'feasible' if out.feasible else 'not feasible'}, {out.time_s:.3g} s")
    return rec


# ----------------------------------------------------------------------------- performance profiles
def _ratio(value: float, best: float) -> float:
    """``value / best`` for costs >= 0 (a best of 0: 1 for 0, inf otherwise)."""
    if best > 0:
        return value / best
    return 1.0 if value <= best else math.inf


def performance_ratios(measure_: dict[str, list[float | None]],
                       known: list[float | None] | None = None) -> dict[str, list[float]]:
    """Dolan-Moré ratios ``r[p, s] = m[p, s] / min_s m[p, s]`` per solver (``measure_``: solver ->
    per-problem values >= 0, ``None`` not solved -> inf; a problem no solver solved: inf for all).
    ``known``: per problem a value reached outside the solvers (the best feasible cost a reference
    reached), a candidate for the minimum too (``None``: none)."""
    solvers = list(measure_)
    n = len(next(iter(measure_.values()))) if measure_ else 0
    out: dict[str, list[float]] = {s: [] for s in solvers}
    for p in range(n):
        vals = [measure_[s][p] for s in solvers]
        extra = [known[p]] if known is not None else []
        finite = [v for v in [*vals, *extra] if v is not None and math.isfinite(v)]
        best = min(finite) if finite else None
        for s, v in zip(solvers, vals):
            out[s].append(math.inf if best is None or v is None or not math.isfinite(v) else _ratio(v, best))
    return out


def profile(ratios: list[float], taus) -> list[float]:
    """``rho(tau)``: the fraction of problems whose ratio is at most ``tau``, per ``tau``."""
    r = np.asarray(ratios, float)
    return [float(np.mean(r <= tau)) if r.size else 0.0 for tau in taus]


RANGE_TOL = 1e-3     # rad (m for a prismatic joint): a plan farther outside a joint range leaves it
VELOCITY_TOL = 1e-3  # rad/s (m/s) above a velocity limit (the planners' own status tolerance, RANGE_STATUS_TOL)
EFFORT_TOL = 1e-6    # N m above an effort limit


def inside_limits(record: dict) -> bool:
    """Whether a run's plan stays in the model's joint ranges (to :data:`RANGE_TOL`), velocity limits (to
    :data:`VELOCITY_TOL`) and effort limits (to :data:`EFFORT_TOL`); a run without a range measurement is
    not inside."""
    rng, eff = record.get("joint_range_excess"), record.get("effort_excess")
    vel = record.get("velocity_excess")
    return (rng is not None and rng <= RANGE_TOL and (vel is None or vel <= VELOCITY_TOL)
            and (eff is None or eff <= EFFORT_TOL))


# the profiles: (kind, the record's measure, which plans count as solved (None: every plan with a value),
# whether the best feasible cost a reference reached joins the minimum)
PROFILE_KINDS = (("cost", "final_cost", None, False), ("time", "time_to_target_s", None, False),
                 ("inside", "final_cost", "inside_limits", True), ("executed", "final_cost", "executed_ok", True))


def profiles(records: list[dict], problems: list[str], solvers: list[str],
             best_feasible: dict[str, float | None] | None = None) -> dict[str, Any]:
    """The profiles of ``records`` over ``problems``: per kind the ratios per solver (problem order) and
    ``rho`` at :data:`TAUS`. ``cost``: the final cost against the best; ``time``: the time to within
    ``within`` of the best cost; ``inside``: the final cost of the plans that stay inside the robot's
    limits (:func:`inside_limits`), a plan that leaves them not solved; ``executed``: the final cost of the
    plans whose execution in Drake is ``ok`` and achieves the task (:func:`executed_ok`), any other not
    solved. ``inside`` and ``executed`` are relative to the best feasible cost known: the best such plan
    or ``best_feasible[problem]`` (the direct-transcription reference's cost from the same start)."""
    by = {(r["problem"], r["solver"]): r for r in records}
    rules = {"inside_limits": inside_limits, "executed_ok": executed_ok}
    out: dict[str, Any] = {"problems": problems, "taus": list(TAUS)}
    for kind, key, rule, with_known in PROFILE_KINDS:
        m = {s: [by[(p, s)][key] if (p, s) in by and (rule is None or rules[rule](by[(p, s)])) else None
                 for p in problems] for s in solvers}
        known = [(best_feasible or {}).get(p) for p in problems] if with_known else None
        ratios = performance_ratios(m, known)
        out[kind] = {"ratios": ratios, "rho": {s: profile(ratios[s], TAUS) for s in solvers}}
    return out


def plot_profiles(doc: dict[str, Any], path: Path) -> Path:
    """Both profiles as one PNG: rho(tau) against tau (log axis), a step line per solver."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from raico.pipeline.engine.atomic import write_file_atomic

    prof = doc["profiles"]["all"]
    solvers = list(prof["cost"]["ratios"])
    n = len(prof["problems"])
    kinds = [("cost", "final cost within tau x the best"),
             ("time", f"time to within {doc['within'] * 100:g} % of the best cost,\nwithin tau x the fastest"),
             ("inside", "final cost within tau x the best feasible cost known\n(a plan outside the limits: not solved)"),
             ("executed", "final cost within tau x the best feasible cost known\n(solved: executed ok, task achieved)")]
    kinds = [k for k in kinds if k[0] in prof]
    fig, axes = plt.subplots(1, len(kinds), figsize=(5.0 * len(kinds), 4.4))
    for ax, (kind, title) in zip(axes, kinds):
        finite = [r for s in solvers for r in prof[kind]["ratios"][s] if math.isfinite(r)]
        top = max(10.0, 1.5 * max(finite)) if finite else 10.0
        taus = np.geomspace(1.0, top, 400)
        for i, s in enumerate(solvers):
            ax.step(taus, profile(prof[kind]["ratios"][s], taus), where="post", label=s, lw=1.8,
                    ls="-" if i < 6 else "--")
        ax.set_xscale("log")
        ax.set_ylim(-0.02, 1.02)
        ax.set_xlabel("tau")
        ax.set_ylabel(f"fraction of the {n} problems")
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=8, loc="lower center", ncol=min(len(solvers), 7), frameon=False)
    fig.suptitle(f"{doc['suite']}: Dolan-Moré performance profiles ({n} problems; a cell without a result counts "
                 "as not solved)", fontsize=10)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_file_atomic(path, buf.getvalue())
    return path


def plot_iterations(doc: dict[str, Any], path: Path) -> Path | None:
    """Per problem (a row), per solver (a line): the cost per iteration (left, log axis) and beside it the
    constraint violation per iteration (right: the iterate's largest joint-range excess,
    :func:`iterate_range_excess`; the axis symmetric-log, 0 inside the ranges to :data:`RANGE_TOL`); one PNG.
    ``None`` where no run recorded its iterations."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from raico.pipeline.engine.atomic import write_file_atomic

    recs = [r for r in doc["records"] if r.get("iteration_costs")]
    problems = [p for p in doc["budgets"] if any(r["problem"] == p for r in recs)]
    if not problems:
        return None
    solvers = list(doc["solvers"])
    colors = {s: f"C{i % 10}" for i, s in enumerate(solvers)}
    fig, axes = plt.subplots(len(problems), 2, figsize=(10, 2.1 * len(problems) + 0.8), squeeze=False)
    for row, p in zip(axes, problems):
        for r in (r for r in recs if r["problem"] == p):
            c = np.array([np.nan if v is None else v for v in r["iteration_costs"]], float)
            row[0].plot(np.arange(1, len(c) + 1), c, color=colors[r["solver"]], lw=1.3, label=r["solver"])
            v = r.get("iteration_range_excess")
            if v:
                e = np.array([np.nan if x is None else x for x in v], float)
                row[1].plot(np.arange(len(e)), e, color=colors[r["solver"]], lw=1.3)
        row[0].set_yscale("log")
        row[0].set_ylabel(p, fontsize=8)
        row[1].set_yscale("symlog", linthresh=RANGE_TOL)
        row[1].axhline(RANGE_TOL, color="k", lw=0.6, ls=":")
        for ax in row:
            ax.grid(alpha=0.3)
            ax.tick_params(labelsize=7)
    axes[0][0].set_title("cost per iteration", fontsize=9)
    axes[0][1].set_title(f"largest joint-range excess per iteration (rad; dotted: {RANGE_TOL:g})", fontsize=9)
    axes[-1][0].set_xlabel("iteration")
    axes[-1][1].set_xlabel("iteration (0: the initial trajectory)")
    handles = [plt.Line2D([], [], color=colors[s], lw=1.5) for s in solvers]
    fig.legend(handles, solvers, fontsize=8, loc="lower center", ncol=min(len(solvers), 5), frameon=False)
    fig.tight_layout(rect=(0, 0.6 / (2.1 * len(problems) + 0.8), 1, 1))
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_file_atomic(path, buf.getvalue())
    return path


# ----------------------------------------------------------------------------- the page
def _f(x: Any, spec: str = ".4g") -> str:
    if x is None:
        return "-"
    if isinstance(x, float) and not math.isfinite(x):
        return "inf"
    return format(x, spec)


def summary(suite: Suite, records: list[dict], meta: dict[str, Any],
            references: dict[str, dict] | None = None) -> dict[str, Any]:
    """The suite's document: the records, the profiles over every problem and over the problems every
    solver ran (no empty cell for an expressibility or input reason), the budgets, and per problem the
    direct-transcription reference (``references``: problem -> :func:`reference_record`), whose feasible
    cost joins the best feasible cost known."""
    problems = [p.label for p in suite.problems]
    solvers = [s.label for s in suite.solvers]
    ran_all = [p for p in problems if all(r["key"] for r in records if r["problem"] == p)]
    references = references or {}
    best_feasible = {p: r["cost"] for p, r in references.items() if r.get("feasible") and r.get("cost") is not None}
    executed = [r for r in records if r["key"]]
    return {"suite": suite.name, "file": str(suite.path), "description": suite.description, "within": suite.within,
            "budgets": {p.label: {"iterations": p.iterations, "time_budget_s": p.time_budget_s, "start": p.start,
                                  "dynamics": p.dynamics or "the file's"} for p in suite.problems},
            "solvers": {s.label: s.options for s in suite.solvers}, "notes": list(suite.notes), **meta,
            "records": records, "references": references,
            "executions": {"runs": len(executed), "ok_achieved": sum(map(executed_ok, executed)),
                           "problems": len(problems),
                           "problems_default_ok": _default_ok(records, problems, suite)},
            "profiles": {"all": profiles(records, problems, solvers, best_feasible),
                         "every_solver_ran": profiles(records, ran_all, solvers, best_feasible)}}


DEFAULT_SOLVER = "R-AICO robust, bounded"   # the entry with a problem file's default plan options
OWN_SOLVER = "raico"   # the report lists where this solver's entries (the thesis's method) lose


def _default_ok(records: list[dict], problems: list[str], suite: Suite) -> int | None:
    """On how many problems the default plan (the suite's :data:`DEFAULT_SOLVER` entry) executes ``ok``
    and achieves its task; None where the suite has no such entry."""
    if not any(s.label == DEFAULT_SOLVER for s in suite.solvers):
        return None
    by = {(r["problem"], r["solver"]): r for r in records}
    return sum(executed_ok(by[(p, DEFAULT_SOLVER)]) for p in problems if (p, DEFAULT_SOLVER) in by)


def _raico_losses(doc: dict[str, Any], by: dict, problems: list[str]) -> list[str]:
    """One line per problem on which the best of R-AICO's entries (solver ``raico``) ends above 1.1x the
    best final cost: its ratio and the solver that set the best."""
    raico = [s for s, o in doc["solvers"].items() if o.get("solver") == OWN_SOLVER]
    if not raico:
        return []
    out = []
    for p in problems:
        best = min((r for s, r in ((s, by[(p, s)]) for s in doc["solvers"]) if r["final_cost"] is not None),
                   key=lambda r: r["final_cost"], default=None)
        if best is None:
            continue
        mine = [by[(p, s)] for s in raico if by[(p, s)]["cost_ratio"] is not None]
        top = min(mine, key=lambda r: r["cost_ratio"], default=None)
        if top is None or top["cost_ratio"] > 1.1:
            what = "no result" if top is None else f"{_f(top['cost_ratio'], '.3g')}x ({top['solver']})"
            out.append(f"- {p}: R-AICO's best {what}; the best {_f(best['final_cost'])} by {best['solver']}")
    head = (f"Where R-AICO ({', '.join(raico)}: the best of them) ends above 1.1x the best final cost: "
            f"{len(out)} of {len(problems)} problems" + (":" if out else "."))
    return [head, "", *out] if out else [head]


def markdown(doc: dict[str, Any], png_name: str = "suite_profiles.png") -> str:
    """The suite's page: per-problem cost and time grids, every run's numbers, both profiles."""
    recs = doc["records"]
    solvers = list(doc["solvers"])
    problems = list(doc["budgets"])
    by = {(r["problem"], r["solver"]): r for r in recs}
    notes: dict[str, int] = {}

    def why(r) -> str:
        if not r["reason"]:
            return "-"
        n = notes.setdefault(r["reason"], len(notes) + 1)
        return f"- [{n}]"

    within = f"{doc['within'] * 100:g} %"
    ran = [r for r in recs if r["key"]]
    cached = sum(r.get("cached", False) for r in ran)
    lines = [f"# The solver suite: {doc['suite']}", "",
             f"Measured by `raico bench suite` ({doc.get('date', '')}; {doc.get('machine', '')}; "
             f"{len(ran) - cached} of its {len(ran)} runs computed in this call, "
             f"{cached} read from the cache with the times of the call that computed them). "
             f"{len(problems)} problems x {len(solvers)} solvers, each run an ordinary cached plan (`raico exp show "
             f"{doc['suite']}`), one run each, seed 0, the problem's start posture. Final cost: raico's cost of the "
             "plan at the budget (the cost of the last iteration finished within the time budget where the run "
             f"took longer). Time: the solver's own clock to within {within} of the best final cost any solver "
             "reached on the problem. Times on a shared machine: ratios mean more than seconds.", "",
             "## Final cost (ratio to the best)", "",
             "| problem | budget | " + " | ".join(solvers) + " |", "|---|---|" + "---|" * len(solvers)]
    for p in problems:
        b = doc["budgets"][p]
        cells = []
        for s in solvers:
            r = by[(p, s)]
            cells.append(why(r) if r["final_cost"] is None else
                         f"{_f(r['final_cost'])} ({_f(r['cost_ratio'], '.3g')}x)")
        lines.append(f"| {p} | {b['iterations']} it, {_f(b['time_budget_s'], 'g')} s, {b['start']} | "
                     + " | ".join(cells) + " |")
    lines += ["", *_raico_losses(doc, by, problems), "", f"## Time to within {within} of the best cost (s)", "",
              "| problem | " + " | ".join(solvers) + " |", "|---|" + "---|" * len(solvers)]
    for p in problems:
        cells = []
        for s in solvers:
            r = by[(p, s)]
            t = r["time_to_target_s"]
            cells.append(_f(t, ".3g") if t is not None else (why(r) if r["reason"] else "not reached"))
        lines.append(f"| {p} | " + " | ".join(cells) + " |")
    lines += ["", *_execution_section(doc, by, problems, solvers), "", "## Every run", "",
              "| problem | solver | status | iterations | final cost | wall (s) | time to target (s) "
              "| joint range excess | velocity excess | effort excess (N m) | inside | execution | task | plan |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in recs:
        status = r["status"] + (" (over the time budget)" if r["over_time_budget"] else "")
        lines.append(f"| {r['problem']} | {r['solver']} | {status} | {_f(r['iterations'], 'd')} | "
                     f"{_f(r['final_cost'])} | {_f(r['wall_time_s'], '.3g')} | {_f(r['time_to_target_s'], '.3g')} | "
                     f"{_f(r['joint_range_excess'], '.3g')} | {_f(r.get('velocity_excess'), '.3g')} | "
                     f"{_f(r['effort_excess'], '.3g')} | "
                     f"{_yes(r.get('inside_limits'))} | {r.get('execution') or '-'} | {r.get('task_note') or '-'} | "
                     f"{r['key'] or why(r)} |")
    lines += ["", "Joint range excess: the largest distance of a planned joint position outside the model's range "
              "(rad; m for a prismatic joint). Velocity excess: the largest planned joint speed above the model file's "
              "velocity limit (rad/s; steps 1..T). Effort excess: the largest torque above a joint's effort limit (for "
              "pseudo-dynamics the torques of the planned accelerations). Inside: all three within "
              f"{RANGE_TOL:g} rad, {VELOCITY_TOL:g} rad/s and {EFFORT_TOL:g} N m. Execution: execute's status of the plan run in Drake "
              "(`raico execute`, its defaults); task: execute's one judgement (`executed_task`: every via-point term "
              "within its tolerance, and the status ok).", ""]
    for name, title in (("all", "every problem"), ("every_solver_ran", "the problems every solver ran")):
        prof = doc["profiles"][name]
        taus = prof["taus"]
        lines += [f"## Performance profiles over {title} ({len(prof['problems'])})", "",
                  "rho(tau): the fraction of problems on which the solver's final cost is within tau x the best "
                  f"(cost), and on which it came within {within} of the best cost within tau x the fastest "
                  "solver's time (time).", "",
                  "| solver | " + " | ".join(f"cost {t:g}" for t in taus) + " | "
                  + " | ".join(f"time {t:g}" for t in taus) + " |",
                  "|---|" + "---|" * (2 * len(taus))]
        for s in solvers:
            lines.append(f"| {s} | " + " | ".join(f"{v:.2f}" for v in prof["cost"]["rho"][s]) + " | "
                         + " | ".join(f"{v:.2f}" for v in prof["time"]["rho"][s]) + " |")
        lines.append("")
        if "executed" in prof:
            lines += ["Executed: the final cost of the plans whose execution in Drake ends `ok` and achieves the "
                      "task, against the best feasible cost known (the best such plan, or the direct-transcription "
                      "reference's where it is lower); any other plan counts as not solved.", "",
                      "| solver | " + " | ".join(f"executed {t:g}" for t in taus) + " |", "|---|" + "---|" * len(taus)]
            lines += [f"| {s} | " + " | ".join(f"{v:.2f}" for v in prof["executed"]["rho"][s]) + " |"
                      for s in solvers]
            lines.append("")
        if "inside" in prof:
            lines += [f"Inside the limits: the final cost of the plans that stay in every joint range (to {RANGE_TOL:g} "
                      f"rad), velocity limit (to {VELOCITY_TOL:g} rad/s) and effort limit (to {EFFORT_TOL:g} N m) against the best feasible cost known (the best "
                      "such plan, or the reference's); a plan that leaves them counts as not solved.", "",
                      "| solver | " + " | ".join(f"inside {t:g}" for t in taus) + " |", "|---|" + "---|" * len(taus)]
            lines += [f"| {s} | " + " | ".join(f"{v:.2f}" for v in prof["inside"]["rho"][s]) + " |" for s in solvers]
            lines.append("")
    lines += [f"![performance profiles]({png_name})", "",
              "The cost and the constraint violation per iteration of every run (the iterate's largest joint-range "
              "excess at the steps a plan keeps of its iterates): "
              f"![cost and constraint violation per iteration]({png_name.replace('_profiles', '_iterations')})", ""]
    if notes or doc.get("notes"):
        lines += ["## Empty cells and left-out solvers", ""]
        lines += [f"{n}. {text}" for text, n in notes.items()]
        lines += [f"- {text}" for text in doc.get("notes", [])]
        lines.append("")
    return "\n".join(lines)


def _yes(flag: bool | None) -> str:
    return "-" if flag is None else ("yes" if flag else "no")


def _execution_section(doc: dict[str, Any], by: dict, problems: list[str], solvers: list[str]) -> list[str]:
    """The executions as a grid (execute's status and the task verdict per cell), their count, and the
    direct-transcription references."""
    ex = doc.get("executions") or {}
    lines = ["## Executed in Drake", "",
             f"{ex.get('ok_achieved', 0)} of the {ex.get('runs', 0)} plans execute `ok` and achieve their task"
             + (f"; the default plan ({DEFAULT_SOLVER}) on {ex['problems_default_ok']} of the {ex['problems']} "
                "problems" if ex.get("problems_default_ok") is not None else "") + ". A cell: execute's status, "
             "then `achieved` / `missed` (execute's judgement) and whether the plan stays inside the limits.", "",
             "| problem | " + " | ".join(solvers) + " |", "|---|" + "---|" * len(solvers)]
    for p in problems:
        cells = []
        for s in solvers:
            r = by[(p, s)]
            if not r.get("execution"):
                cells.append("-")
                continue
            task = "-" if r.get("task_achieved") is None else ("achieved" if r["task_achieved"] else "missed")
            cells.append(f"{r['execution']}, {task}" + ("" if r.get("inside_limits") else ", outside"))
        lines.append(f"| {p} | " + " | ".join(cells) + " |")
    refs = doc.get("references") or {}
    if refs:
        lines += ["", "### The direct-transcription reference", "",
                  "Drake's MathematicalProgram over the states and controls of the same discrete dynamics, costs "
                  "and bounds, velocity limits included (raico/pipeline/experiments/transcription.py), warm-started from the best plan inside the limits (else "
                  "the best plan); its cost joins the best feasible cost known where it is feasible.", "",
                  "| problem | solver | warm start | status | cost | feasible | range excess | velocity excess "
                  "| dynamics defect | time (s) |", "|---|---|---|---|---|---|---|---|---|---|"]
        for p, r in refs.items():
            lines.append(f"| {p} | {r.get('solver', '-')} | {r.get('warm_start', '-')} | {r.get('status', '-')} | "
                         f"{_f(r.get('cost'))} | {_yes(r.get('feasible'))} | {_f(r.get('range_excess'), '.3g')} | "
                         f"{_f(r.get('velocity_excess'), '.3g')} | {_f(r.get('defect'), '.3g')} | {_f(r.get('time_s'), '.3g')} |")
    return lines


# ----------------------------------------------------------------------------- one call
def bench(cache, suite: Suite, executor, say: Callable[[str], None], out: Path,
          progress: Callable[[Any], None] | None = None) -> dict[str, Any]:
    """Run the suite (:func:`run`), measure it, and write ``out/<name>.json``, ``<name>.md`` and
    ``<name>_profiles.png``; the document."""
    import json

    from raico.pipeline.engine.atomic import write_file_atomic
    from raico.pipeline.engine.runner import finite_json

    for note in suite.notes:
        say(note)
    meta = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "machine": f"{os.cpu_count()} cpus, load {os.getloadavg()[0]:.1f} at the start, Python "
                       f"{platform.python_version()}"}
    all_cells = run(cache, suite, executor, say, progress)
    records = measure(cache, suite, all_cells)
    refs = {}
    if suite.reference:
        start = time.perf_counter()
        for p in suite.problems:
            spent = time.perf_counter() - start > suite.reference_total_s
            try:
                rec = reference_record(cache, suite, p, records, say, cached_only=spent)
            except (ValueError, RuntimeError) as e:   # a problem Drake's program cannot take: said, the suite goes on
                say(f"suite: {p.label}: no transcription reference: {' '.join(str(e).split())}")
                rec = None
            if rec is not None:
                refs[p.label] = rec
    doc = summary(suite, records, meta, refs)
    doc["machine"] += f", load {os.getloadavg()[0]:.1f} at the end"
    out.mkdir(parents=True, exist_ok=True)
    png = plot_profiles(doc, out / f"{suite.name}_profiles.png")
    iters = plot_iterations(doc, out / f"{suite.name}_iterations.png")
    write_file_atomic(out / f"{suite.name}.json", json.dumps(finite_json(doc), indent=1, allow_nan=False))
    write_file_atomic(out / f"{suite.name}.md", markdown(doc, png.name))
    doc["outputs"] = [str(out / f"{suite.name}.json"), str(out / f"{suite.name}.md"), str(png),
                      *([str(iters)] if iters else [])]
    return doc
