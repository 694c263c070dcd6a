"""The thesis's experiments (figs. 3.2-3.4, 4.1-4.3) and raico's own beside them: read from their files, the
parallel sweep, figure, claims.

Each experiment is a file under ``raico/thesis/experiments/`` (:data:`THESIS_FILES`), read by the same loader as
any user's experiment (``raico.pipeline.experiments.expfile``: ``raico exp run raico/thesis/experiments/fig3.2a.toml`` runs its
plans, with the same cache keys): its solver variants (``[[point]]``), initial states (``seeds``), the
``--quick`` profile, the claims checked on it (Python functions of ``raico.thesis.claims``, named in the
file) and, under ``[reproduce]``, which plans are executed and how. Every plan and learning loop's config is
made from the file by ``raico.pipeline.experiments.expfile`` (:func:`plan_config`, :func:`learn_config`).

An experiment is a set of plan runs: every solver variant on every initial state
``q0 = default + N(0, 0.05^2)`` (seeds 0..9). Each run is a cached plan artifact, so a second
call is served from the cache. For the Nao figures the R-AICO plans are also executed in
Drake (CoG against the support polygon). ``--quick`` uses 2 seeds and fewer iterations.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from raico.pipeline.engine.cache import Cache
from raico.pipeline.engine.executors import Batch, Job
from raico.pipeline.engine.runner import Outcome
from raico.thesis.claims import FDDP_ACCEPT_ANY, FDDP_HELD, FDDP_ILQG_SCHEDULE, FDDP_ROLLOUT

RECORDED_SEEDS = 3  # make reproduce records the thesis solvers' plans, and the executions, of the first this many
#                     initial states (the others: `raico show KEY --open`)


def recorded_seed(seed: int) -> bool:
    """Whether ``make reproduce`` records the runs of initial state ``seed`` (the first ``RECORDED_SEEDS``)."""
    return seed < RECORDED_SEEDS


@dataclass(frozen=True)
class Variant:
    solver: str
    alpha: float = 0.0
    relinearize: bool = True  # AICO only: False is the ablation without sweep relinearization
    iterations: int | None = None  # own budget (the crocoddyl baseline), else the experiment's
    quick_iterations: int | None = None
    schedule: str = "fixed"  # R-AICO's alpha schedule: the thesis's fixed one, or "adaptive" / "robust" (beyond it)
    seeds: int | None = None  # own number of initial states (ablations), else the experiment's
    gamma: float = 1.0  # R-AICO: alpha^[n] = alpha^[n-1] gamma (thesis §3.5; the thesis's figures use 1)
    start: str = "held"  # AICO/R-AICO's first trajectory: x0 held (thesis) or the zero-control rollout
    dynamics: str | None = None  # own planning model (the finite-difference ablation), else the experiment's
    belief_rate: float = 1.0  # AICO's learning rates (Algorithm 1 lines 13 and 18; 1: none)
    controller_rate: float = 1.0
    task: str | None = None  # own task (the thesis's set-up beside raico's: TASK_LABELS), else the experiment's
    nudge: float = 0.0  # rad added to every joint of the start (the perturbation test of chaotic runs)

    @property
    def label(self) -> str:
        if self.solver in BASELINE_LABELS:
            return BASELINE_LABELS[self.solver]
        extra = (f", gamma={self.gamma:g}" if self.gamma != 1.0 else "") + (
            ", rollout start" if self.start == "rollout" else "") + (
            ", finite differences" if self.dynamics == "analytic-fd" else "") + (
            f", {INTEGRATOR_NAMES[self.dynamics]} pseudo-dynamics" if self.dynamics in INTEGRATOR_NAMES else "") + (
            f", belief rate {self.belief_rate:g}" if self.belief_rate != 1.0 else "") + (
            f", controller rate {self.controller_rate:g}" if self.controller_rate != 1.0 else "") + (
            f", {TASK_LABELS[self.task]}" if self.task is not None else "") + (
            f", start {self.nudge:+g} rad" if self.nudge else "")
        if self.solver == "raico" and self.schedule in ("adaptive", "robust"):
            return f"R-AICO {self.schedule} (a0={self.alpha:g}{extra})"
        base = {"ilqg": "iLQG", "aico": "AICO"}.get(self.solver, f"R-AICO a={self.alpha:g}") + extra
        return base if self.relinearize else f"{base} (no sweep relinearization)"

    @property
    def recorded(self) -> bool:
        """Whether ``make reproduce`` records this variant's plans (those of its first ``RECORDED_SEEDS`` initial
        states): the thesis's solvers in the thesis's set-up (iLQG, AICO, R-AICO with a fixed alpha); the ablations,
        baselines and long-budget references, and the other initial states, are recorded on demand (``raico show KEY
        --open`` writes one from the cache): a plan recording takes 0.3-0.4 s; all of the thesis solvers' plans were
        270 recordings, and recording only the first 3 initial states cut ``make reproduce`` from 1210 to 1142 s of
        CPU (624 to 588 s wall, on the 2 cores)."""
        return self.solver in ("ilqg", "aico", "raico") and self == Variant(self.solver, self.alpha)  # all else default

    def records(self, seed: int) -> bool:
        """Whether ``make reproduce`` records this variant's plan of initial state ``seed`` (``recorded``)."""
        return self.recorded and recorded_seed(seed)

    def seed_count(self, exp_seeds: int, quick: bool) -> int:
        """Initial states this variant runs on: 2 with --quick, else its own count or the experiment's."""
        return 2 if quick else min(self.seeds or exp_seeds, exp_seeds)


# The tasks a figure's point may run in place of the figure's, as the labels say them: the thesis's set-up beside
# raico's (the claims judge these variants in rows of their own, "with the thesis's start" / "cost")
TASK_LABELS = {"reach-zero": "zero posture", "balance-thesis": "thesis's cost"}


# The crocoddyl baseline's labels (its points need crocoddyl: the extra raico[baseline], which `make install` installs)
BASELINE_LABELS = {"fddp": FDDP_HELD, "fddp-rollout": FDDP_ROLLOUT, "fddp-rollout-accept-any": FDDP_ACCEPT_ANY,
                   "fddp-rollout-ilqg-schedule": FDDP_ILQG_SCHEDULE}


# the pseudo-dynamics integrators (appendix C's comparison) by their planning model's name, as the labels say them
INTEGRATOR_NAMES = {"pseudo": "backward Euler", "pseudo-euler": "Euler", "pseudo-heun": "Heun"}


@dataclass(frozen=True)
class Experiment:
    """A plan figure, made from its file by :func:`load_figure` (the fields are what the figure, tables and
    claims read; the runs' configs come from the file itself, :func:`plan_config`)."""

    id: str
    plant: str
    task: str
    dynamics: str
    variants: tuple[Variant, ...]
    iterations: int
    quick_iterations: int
    description: str
    seeds: int = 10
    execute: tuple[Variant, ...] = ()
    claims: tuple[str, ...] = field(default=())
    integrators: tuple[Variant, ...] = ()  # appendix C's comparison: own table, not in the cost figure
    # beyond the thesis the executed variants' plans also carried out by the whole-body stabilizer
    # from a standing start (ExecuteConfig controller=wbc, start=standing), beside the joint PD of the thesis rows
    stabilized: bool = False
    # the plan's balance option (raico/stages/plan/balance.py) and its margin (m); "none" for the thesis's figures
    balance: str = "none"
    balance_margin: float = 0.015
    # the executed variants' plans carried out by the joint PD from the plan's start (the thesis rows); False: only
    # the stabilizer's executions (a figure beyond the thesis whose plans a welded-foot PD cannot carry out)
    execute_pd: bool = True
    # the stabilizer's noise sweep every executed plan at every noise level (stabilized figures)
    noise_wbc: bool = True
    source: str = field(default="", compare=False)   # the experiment's file
    # the file as raico.pipeline.experiments.expfile reads it: (its runs, its --quick profile's runs)
    profiles: tuple = field(default=(), compare=False, repr=False)

    def integrator_variants(self, quick: bool) -> tuple[Variant, ...]:
        """The integrator comparison's variants (none with --quick)."""
        return () if quick else self.integrators

    def run_count(self, quick: bool) -> int:
        """Plan runs of the figure (its variants and the integrator comparison's)."""
        return sum(v.seed_count(self.seeds, quick) for v in (*self.variants, *self.integrator_variants(quick)))


def plan_config(exp: Experiment, v: Variant, seed: int, quick: bool):
    """The plan config of variant ``v`` at initial state ``seed``, made from the experiment's file by
    ``raico.pipeline.experiments.expfile`` (its ``--quick`` profile with ``quick``): the config ``raico exp run`` makes."""
    from raico.pipeline.experiments import expfile

    if not exp.profiles:
        raise ValueError(f"{exp.id}: an experiment without a file has no plan configs")
    fexp = exp.profiles[1 if quick else 0]
    return expfile.first_config(fexp, expfile.Run(fexp.variant(v.label), seed)).normalized()


def _job(args) -> dict:
    """One stage run in a worker process: ``(root, stage, config, record) -> Outcome fields``."""
    root, stage, cfg, record = args
    from raico.pipeline.engine import runner

    return runner.run(Cache(root), stage, cfg, record=record).__dict__


def stage_job(cache: Cache, stage: str, cfg, record: bool, label: str = "") -> Job:
    """A stage run for the scheduler: looked up here (a cached run is never submitted), else ``_job``."""
    from raico.pipeline.engine import runner

    return Job(_job, (str(cache.root), stage, cfg, record), label,
               lambda: runner.lookup(cache, stage, cfg, record=record))


def as_outcomes(values: list) -> list[Outcome]:
    """Scheduler results as outcomes: a lookup gives an ``Outcome``, a worker its fields."""
    return [v if isinstance(v, Outcome) else Outcome(**v) for v in values]


def experiment_flow(cache: Cache, exp: Experiment, quick: bool = False, record: bool = True):
    """The runs of ``exp`` as a scheduler flow (``raico.pipeline.engine.executors``): its plans, then the runs
    that depend on them (the executions of the chosen variants, the noise sweep, and the open-loop
    integrations of the integrator comparison's plans). Returns ``{"plans", "executions", "noise",
    "integrators"}`` (``integrators``: the comparison's plans, each with its ``integration``)."""
    from raico.stages.execute.config import ExecuteConfig

    integ = exp.integrator_variants(quick)
    runs = [(v, s, plan_config(exp, v, s, quick)) for v in (*exp.variants, *integ)
            for s in range(v.seed_count(exp.seeds, quick))]
    outs = yield Batch("plan", [stage_job(cache, "plan", cfg, record and v.records(s), f"{v.label} seed {s}")
                                for v, s, cfg in runs])
    every = [{"variant": v, "seed": s, "outcome": o, "iterations": cfg.iterations}   # the run's budget
             for (v, s, cfg), o in zip(runs, as_outcomes(outs))]
    n_main = len(every) - sum(v.seed_count(exp.seeds, quick) for v in integ)
    plans, integ_plans = every[:n_main], every[n_main:]
    ex_jobs = [stage_job(cache, "execute", ExecuteConfig(plan=f"plan/{p['outcome'].key}"),
                         record and recorded_seed(p["seed"]),
                         f"{p['variant'].label} seed {p['seed']}")
               for p in plans if p["variant"] in exp.execute and exp.execute_pd]
    ex_jobs += [stage_job(cache, "execute", ExecuteConfig(plan=f"plan/{p['outcome'].key}", **STABILIZER),
                          record and recorded_seed(p["seed"]), f"{p['variant'].label} seed {p['seed']}, stabilizer")
                for p in plans if exp.stabilized and p["variant"] in exp.execute]
    # no recordings of the integrations (about 0.4 s each; `raico execute --plan KEY --open-loop` writes one from the cache)
    integ_jobs = [stage_job(cache, "execute", ExecuteConfig(plan=f"plan/{p['outcome'].key}", open_loop=True), False,
                            f"{p['variant'].label} seed {p['seed']}, open loop") for p in integ_plans]
    noise = noise_runs(exp, plans, quick)
    # the sweep's noisy runs are not recorded here (a free-standing Nao's recording takes 0.6 s; `raico show KEY --open`
    # writes one from the cache); level 0 is the figure's own execution, recorded with it
    noise_jobs = [stage_job(cache, "execute", r["config"],
                            record and recorded_seed(r["plan_seed"]) and not any(r["level"]),
                            f"{r['label']} seed {r['plan_seed']}{', stabilizer' if r['controller'] == 'wbc' else ''}, "
                            f"noise x0 {r['level'][0]:g} rad, process {r['level'][1]:g} N m") for r in noise]
    jobs = ex_jobs + noise_jobs + integ_jobs  # a Nao figure's executions are its sweep's level 0: each runs once
    outs = as_outcomes((yield Batch("execute", jobs)) if jobs else [])
    n_ex, n_noise = len(ex_jobs), len(noise_jobs)
    return {"plans": plans, "executions": outs[:n_ex],
            "noise": [{**{k: v for k, v in r.items() if k != "config"}, "outcome": o}
                      for r, o in zip(noise, outs[n_ex:n_ex + n_noise])],
            "integrators": [{**p, "integration": o} for p, o in zip(integ_plans, outs[n_ex + n_noise:])]}


# the stabilized executions' settings the whole-body QP from the standing start
STABILIZER: dict[str, Any] = {"controller": "wbc", "start": "standing"}


# ----------------------------------------------------------------------------- robustness under noise
# The swept variant's plans of the first NOISE_RUNS initial states are executed at every noise
# level: (x0 noise rad, process noise N m per planning step and joint). Plan i runs with execution
# seed i (level 0 is deterministic: seed 0, the figure's own execution for the Nao). Success:
# execution status ok.
NOISE_LEVELS = ((0.0, 0.0), (0.02, 0.5))
NOISE_RUNS = 3  # per level (--quick: 2)
# NOISE_SWEEPS (figure id -> the variant whose plans the joint PD's sweep executes): from the files, below


def noise_runs(exp: Experiment, plans: list[dict], quick: bool) -> list[dict]:
    """The sweep's executions of ``exp``: ``{"controller", "level", "plan_seed", "seed", "config"}`` each. The joint
    PD's (the figures of ``NOISE_SWEEPS``): the swept variant's plans of the first ``NOISE_RUNS`` initial states at
    every level; the stabilizer's (a ``stabilized`` figure): every executed plan at every level (level 0 is
    the figure's own execution with the stabilizer)."""
    from raico.stages.execute.config import ExecuteConfig

    out = []

    def add(controller: str, chosen: list[dict], extra: dict) -> None:
        for level in NOISE_LEVELS:
            for p in chosen:
                seed = p["seed"] if any(level) else 0
                out.append({"controller": controller, "level": level, "plan_seed": p["seed"], "seed": seed,
                            "label": p["variant"].label,
                            "config": ExecuteConfig(plan=f"plan/{p['outcome'].key}", x0_noise=level[0],
                                                    process_noise=level[1], seed=seed, **extra)})

    variant = NOISE_SWEEPS.get(exp.id)
    if variant is not None and exp.execute_pd:
        add("pd", [p for p in plans if p["variant"] == variant and p["seed"] < (2 if quick else NOISE_RUNS)], {})
    if exp.stabilized and exp.noise_wbc:
        add("wbc", [p for p in plans if p["variant"] in exp.execute], STABILIZER)
    return out


# ----------------------------------------------------------------------------- analysis
def cost_curves(cache: Cache, plans: list[dict], variant: Variant, what: str = "costs") -> np.ndarray:
    """``(seeds, iterations)`` per-iteration ``what`` (``costs`` or ``elapsed`` wall time, s) of a
    variant's runs; runs that stopped early hold their last value, diverged runs are NaN after
    they diverged."""
    from raico.pipeline.engine.artifacts import as_artifact

    curves = []
    for p in plans:
        if p["variant"] != variant:
            continue
        d = as_artifact(cache.require("plan", p["outcome"].key)).arrays("plan.npz", (what,))
        curves.append(d[what].astype(float) if what in d else np.zeros(0))
    if not curves:
        return np.zeros((0, 0))
    n = max(len(c) for c in curves)
    out = np.full((len(curves), n), np.nan)
    for i, c in enumerate(curves):
        out[i, :len(c)] = c
        if len(c) and np.isfinite(c[-1]) and len(c) < n:
            out[i, len(c):] = c[-1]
    return out


def summarize(plans: list[dict], variant: Variant, cache: Cache | None = None) -> dict:
    """The variant's summary (``raico.stages.evaluate.summary``) over its runs; with ``cache`` each run's
    per-iteration costs (``plan.npz``) join its metrics as ``cost_history`` (the convergence claims'
    cost curves)."""
    return plan_summary(variant.label, [r for _, r in variant_runs(plans, variant, cache)])


def plan_summary(label: str, runs: list[dict]) -> dict:
    """``raico.stages.evaluate.summary.summarize`` of a variant's runs, with the medians over its runs of what
    :func:`counterbalance` measured beside the excursions (``cog_drift``, ``cog_drift_held``, m) where the runs
    have them."""
    from raico.stages.evaluate.summary import median
    from raico.stages.evaluate.summary import summarize as summary

    out = summary(label, runs)
    for key in ("cog_drift", "cog_drift_held"):
        vals = [r["metrics"][key] for r in runs if key in r.get("metrics", {})]
        if vals:
            out[f"{key}_median"] = median(np.asarray(vals, float))
    return out


def variant_runs(plans: list[dict], variant: Variant, cache: Cache | None = None) -> list[tuple[int, dict]]:
    """``(seed, {"status", "metrics"})`` of each of the variant's runs, as :func:`summarize` reads them."""
    runs = []
    for p in plans:
        if p["variant"] != variant:
            continue
        m = dict(p["outcome"].metrics)
        if cache is not None:
            from raico.pipeline.engine.artifacts import as_artifact

            art = as_artifact(cache.require("plan", p["outcome"].key))
            nao_reach = art.config.get("plant") == "nao" and art.config.get("task") in ("reach", "reach-zero")
            d = art.arrays("plan.npz", ("costs", "X") if nao_reach else ("costs",))
            c = d.get("costs")
            m["cost_history"] = [float(x) if np.isfinite(x) else None for x in np.asarray(c if c is not None else [])]
            if nao_reach:
                m.update(counterbalance(d["X"]))
        runs.append((p["seed"], {"status": p["outcome"].status, "metrics": m}))
    return runs


COUNTERBALANCE_JOINTS = ("HeadYaw", "HeadPitch", "LShoulderPitch", "LShoulderRoll", "LElbowYaw", "LElbowRoll")


def counterbalance(X: np.ndarray) -> dict:
    """How far a Nao plan moves what no objective names (thesis Fig. 3.3D: "To counter balance, the robot
    moves its left hand and the head"): the largest excursion from the start of the head joints and of
    the left arm's joints (rad), and of the left hand's position (m), over the plan ``X (T+1, n_x)``; and what
    that motion does to balance: ``cog_drift``, the largest horizontal distance (m) of the CoG from its start (over
    the support the plan starts on) over the plan, and ``cog_drift_held``, the same with the head and left-arm joints
    held at their start angles (the plan without its counterbalancing motion). The motion counterbalances where
    the first is the smaller."""
    from raico.plants.robots import shared_robot
    from raico.plants.taskmaps import CenterOfMass, EndEffectorPosition

    robot = shared_robot("nao")
    n = robot.n_q
    Q = np.asarray(X, float)[:, :n]
    if not np.all(np.isfinite(Q)):
        return {}
    dq = np.abs(Q - Q[0])
    idx = {j: robot.joint_names.index(j) for j in COUNTERBALANCE_JOINTS}
    head = max(float(dq[:, idx[j]].max()) for j in COUNTERBALANCE_JOINTS if j.startswith("Head"))
    arm = max(float(dq[:, idx[j]].max()) for j in COUNTERBALANCE_JOINTS if j.startswith("L"))
    P, _ = EndEffectorPosition(robot, "l_gripper").values_and_jacobians(Q[::5])
    hand = float(np.linalg.norm(P - P[0], axis=1).max())
    held = Q.copy()
    cols = list(idx.values())
    held[:, cols] = Q[0, cols]
    cog = CenterOfMass(robot, axes=(0, 1))
    drift = [float(np.linalg.norm(C - C[0], axis=1).max()) for C in
             (cog.values_and_jacobians(Qx[::5])[0] for Qx in (Q, held))]
    return {"head_joint_excursion": head, "left_arm_joint_excursion": arm, "left_hand_excursion": hand,
            "cog_drift": drift[0], "cog_drift_held": drift[1]}


# ----------------------------------------------------------------------------- learning experiments
@dataclass(frozen=True)
class LearnSetting:
    """One curve of a learning figure: a label, its ``LearnConfig`` overrides and its seeds."""

    label: str
    overrides: tuple[tuple[str, object], ...]
    seeds: int = 2
    quick: bool = False  # part of the --quick profile


@dataclass(frozen=True)
class LearnExperiment:
    id: str
    plant: str
    task: str
    description: str
    settings: tuple[LearnSetting, ...]
    base: tuple[tuple[str, object], ...]  # LearnConfig values shared by every setting
    episodes: int
    quick_episodes: int
    claims: tuple[str, ...] = ()
    notes: tuple[tuple[str, str], ...] = ()
    source: str = field(default="", compare=False)
    profiles: tuple = field(default=(), compare=False, repr=False)


def learn_config(exp: LearnExperiment, s: LearnSetting, seed: int, quick: bool):
    """The learn config of setting ``s`` at ``seed``, made from the experiment's file by ``raico.pipeline.experiments.expfile``."""
    from raico.pipeline.experiments import expfile

    if not exp.profiles:
        raise ValueError(f"{exp.id}: an experiment without a file has no learn configs")
    fexp = exp.profiles[1 if quick else 0]
    return expfile.first_config(fexp, expfile.Run(fexp.variant(s.label), seed))


def learn_flow(cache: Cache, exp: LearnExperiment, quick: bool = False, record: bool = True):
    """Every setting's learning loops of ``exp`` as a scheduler flow (one job per loop, each a long
    sequential chain of stage runs). Returns ``{"learns"}``."""
    runs = [(s, k, learn_config(exp, s, k, quick)) for s in exp.settings if s.quick or not quick
            for k in range(1 if quick else s.seeds)]
    jobs = [stage_job(cache, "learn", cfg, record, f"{s.label} seed {k}") for s, k, cfg in runs]
    outs = as_outcomes((yield Batch("learn", jobs)))
    return {"learns": [{"setting": s, "seed": k, "outcome": o} for (s, k, _), o in zip(runs, outs)]}


def summarize_learns(learns: list[dict], leave_out: int | None = None) -> dict[str, dict]:
    """Setting label -> ``raico.stages.evaluate.summary.summarize_learn`` over its seeds (``leave_out``: without that
    seed's loops)."""
    from raico.stages.evaluate.summary import summarize_learn

    learns = [x for x in learns if x["seed"] != leave_out]
    labels = list(dict.fromkeys(x["setting"].label for x in learns))
    out = {}
    for lab in labels:
        runs = [x["outcome"].metrics for x in learns if x["setting"].label == lab]
        with warnings.catch_warnings():  # a seed whose last episodes all diverged has no mean there: NaN, said apart
            warnings.simplefilter("ignore", RuntimeWarning)
            s = summarize_learn(lab, [without_diverged(m) for m in runs])
        s["diverged_by_seed"] = [sum(st == "diverged" for st in m.get("execution_status") or []) for m in runs]
        s["episodes"] = max((len(m.get("execution_status") or []) for m in runs), default=0)
        # a seed whose last execution diverged did not end anywhere: no end angle to rank it by
        s["task_error_last_by_seed"] = [math.inf if (m.get("execution_status") or [None])[-1] == "diverged" else e
                                        for m, e in zip(runs, s["task_error_last_by_seed"])]
        out[lab] = s
    return out


# per-episode numbers measured on an execution: of a diverged execution (the simulation blew up) they are no data
EXECUTION_KEYS = ("gp_error", "rmse_planned_executed", "task_error", "torque_saturation")


def without_diverged(m: dict) -> dict:
    """A learn run's metrics with the numbers of its diverged executions (``execution_status`` "diverged") set to
    None, so that no curve averages them in as if they were data (the summary counts them apart)."""
    bad = [st == "diverged" for st in m.get("execution_status") or []]
    if not any(bad):
        return m
    out = dict(m)
    for key in EXECUTION_KEYS:
        if isinstance(m.get(key), list):
            out[key] = [None if i < len(bad) and bad[i] else v for i, v in enumerate(m[key])]
    return out


# A verdict is fragile where leaving out one seed flips it; with fewer seeds than this, leaving one out leaves
# too little to judge (a median of one run), so it is not tried.
LEAVE_ONE_OUT_MIN = 3


# ----------------------------------------------------------------------------- the experiment files
THESIS_DIR = Path(__file__).resolve().parent / "experiments"
# the files, in the report's order (the figure ids are their [reproduce] figure, else their name)
THESIS_FILES = ("fig3.2a", "fig3.2b", "fig3.2c", "fig3.2d", "fig3.3", "fig3.4", "fig3.4-inside", "fig3.4-single",
                "fig3.4-support", "fig4.1-4.2", "fig4.3")
# a plan experiment's [base] and [[point]] options: those the figures, tables and claims tell variants by
PLAN_BASE = ("plant", "task", "dynamics", "iterations", "q0_std", "balance", "balance_margin")
VARIANT_OPTIONS = {"solver": "solver", "alpha": "alpha", "relinearize": "relinearize", "iterations": "iterations",
                   "alpha_schedule": "schedule", "gamma": "gamma", "start": "start", "dynamics": "dynamics",
                   "belief_rate": "belief_rate", "controller_rate": "controller_rate", "task": "task",
                   "x0_nudge": "nudge"}
REPRODUCE_KEYS = ("figure", "execute", "controllers", "noise_sweep", "stabilizer_noise", "integrators", "notes")
CONTROLLERS = ("pd", "stabilizer")   # the joint PD from the plan's start; the whole-body stabilizer (STABILIZER)


def _count(path: Path, what: str, seeds: tuple[int, ...], of: tuple[int, ...] | None = None) -> int:
    """``len(seeds)``, which must be the first seeds 0..N-1 (the figures count initial states from 0)."""
    from raico.pipeline.errors import BadInput

    if seeds != tuple(range(len(seeds))):
        raise BadInput(f"{path}: {what}: the seeds of a figure are range(N), got {list(seeds)}")
    return len(seeds)


def _labels(path: Path, rep: dict, key: str, by_label: dict) -> list:
    from raico.pipeline.errors import BadInput

    value = rep.get(key, [])
    value = [value] if isinstance(value, str) else value
    unknown = [x for x in value if x not in by_label]
    if unknown:
        raise BadInput(f"{path}: [reproduce] {key}: no point '{unknown[0]}'")
    return [by_label[x] for x in value]


def _plan_experiment(path: Path, full, quick) -> Experiment:
    """The figure of a plan experiment file (its profiles ``full`` and ``quick`` read by raico.pipeline.experiments.expfile)."""
    from raico.pipeline.errors import BadInput

    base = full.base["plan"]
    unknown = [k for k in base if k not in PLAN_BASE]
    if unknown:
        raise BadInput(f"{path}: [base] {unknown[0]}: a figure's base options are {', '.join(PLAN_BASE)}")
    quick_points = {p["label"]: p for p in quick.points}
    by_label: dict[str, Variant] = {}
    for p in full.points:
        extra = [k for k in p if k not in (*VARIANT_OPTIONS, "label", "seeds")]
        if extra:
            raise BadInput(f"{path}: point '{p['label']}': {extra[0]}: a figure's points set "
                           f"{', '.join(VARIANT_OPTIONS)}")
        q = quick_points.get(p["label"], {})
        fields = {VARIANT_OPTIONS[k]: v for k, v in p.items() if k in VARIANT_OPTIONS}
        v = Variant(**{"alpha": 0.0, **fields}, quick_iterations=q.get("iterations") if "iterations" in p else None,
                    seeds=_count(path, f"point '{p['label']}'", p["seeds"]) if p["seeds"] else None)
        if v.label != p["label"]:   # the tables, colours and claims know a variant by its label
            raise BadInput(f"{path}: point '{p['label']}': the figures and claims call these options '{v.label}'")
        by_label[p["label"]] = v
    rep = full.reproduce
    unknown = [k for k in rep if k not in REPRODUCE_KEYS]
    if unknown:
        raise BadInput(f"{path}: [reproduce] {unknown[0]}: valid keys are {', '.join(REPRODUCE_KEYS)}")
    controllers = rep.get("controllers", ["pd"])
    if not controllers or any(c not in CONTROLLERS for c in controllers):
        raise BadInput(f"{path}: [reproduce] controllers: one or both of {', '.join(CONTROLLERS)}")
    integrators = _labels(path, rep, "integrators", by_label)
    defaults = Experiment("", "", "", "", (), 0, 0, "")
    return Experiment(
        id=rep.get("figure", full.name), plant=base["plant"], task=base["task"], dynamics=base.get("dynamics", "pseudo"),
        variants=tuple(v for v in by_label.values() if v not in integrators), iterations=base["iterations"],
        quick_iterations=quick.base["plan"]["iterations"], description=full.description,
        seeds=_count(path, "seeds", full.seeds), execute=tuple(_labels(path, rep, "execute", by_label)),
        claims=full.claims, integrators=tuple(integrators), stabilized="stabilizer" in controllers,
        balance=base.get("balance", defaults.balance), balance_margin=base.get("balance_margin", defaults.balance_margin),
        execute_pd="pd" in controllers, noise_wbc=bool(rep.get("stabilizer_noise", True)), source=str(path),
        profiles=(full, quick))


def _learn_experiment(path: Path, full, quick) -> LearnExperiment:
    """The figure of a learning experiment file."""
    from raico.pipeline.errors import BadInput

    base = full.base["learn"]
    rep = full.reproduce
    unknown = [k for k in rep if k not in ("figure", "notes")]
    if unknown:
        raise BadInput(f"{path}: [reproduce] {unknown[0]}: a learning figure's keys are figure, notes")
    in_quick = {p["label"] for p in quick.points}
    settings = tuple(LearnSetting(p["label"], tuple((k, v) for k, v in p.items() if k not in ("label", "seeds")),
                                  _count(path, f"point '{p['label']}'", p["seeds"] or full.seeds),
                                  quick=p["label"] in in_quick) for p in full.points)
    return LearnExperiment(
        id=rep.get("figure", full.name), plant=base["plant"], task=base["task"], description=full.description,
        settings=settings, base=tuple((k, v) for k, v in base.items() if k not in ("plant", "task", "episodes")),
        episodes=base["episodes"], quick_episodes=quick.base["learn"]["episodes"], claims=full.claims,
        notes=tuple((str(k), str(v)) for k, v in (rep.get("notes") or {}).items()), source=str(path),
        profiles=(full, quick))


def load_figure(path: str | Path) -> Experiment | LearnExperiment:
    """A figure from its experiment file, read by ``raico.pipeline.experiments.expfile`` in full and in its ``--quick`` profile:
    :class:`~raico.pipeline.errors.BadInput` (one line) on anything a figure cannot be made of."""
    from raico.pipeline.errors import BadInput
    from raico.pipeline.experiments import expfile
    from raico.thesis.claims import CLAIMS

    path = Path(path)
    full, quick = expfile.load(path), expfile.load(path, quick=True)
    unknown = [c for c in full.claims if c not in CLAIMS]
    if unknown:
        raise BadInput(f"{path}: claim '{unknown[0]}': no such claim (raico/thesis/claims.py: "
                       f"{', '.join(CLAIMS)})")
    if full.stages == ("plan",):
        return _plan_experiment(path, full, quick)
    if full.stages == ("learn",):
        return _learn_experiment(path, full, quick)
    raise BadInput(f"{path}: a figure's stages are [\"plan\"] (its executions under [reproduce]) or [\"learn\"]")


def _load_figures() -> tuple[dict[str, Experiment], dict[str, LearnExperiment]]:
    plans: dict[str, Experiment] = {}
    learns: dict[str, LearnExperiment] = {}
    for name in THESIS_FILES:
        fig = load_figure(THESIS_DIR / f"{name}.toml")
        if isinstance(fig, LearnExperiment):
            learns[fig.id] = fig
        else:
            plans[fig.id] = fig
    return plans, learns


EXPERIMENTS, LEARN_EXPERIMENTS = _load_figures()


def include_thesis_setups() -> None:
    """Load the figures again with their points that need "thesis-setups" (the thesis's set-ups beside raico's:
    the Nao's reach from the zero posture, its balancing with eq. 3.7's cost, the pendulum with x0 held), in place,
    so every module that holds the figures sees them."""
    from raico.pipeline.experiments import expfile

    os.environ[expfile.THESIS_SETUPS] = "1"
    expfile.available.cache_clear()
    plans, learns = _load_figures()
    EXPERIMENTS.update(plans)
    LEARN_EXPERIMENTS.update(learns)
NOISE_SWEEPS = {e.id: next(v for v in e.variants if v.label == e.profiles[0].reproduce["noise_sweep"])
                for e in EXPERIMENTS.values() if "noise_sweep" in e.profiles[0].reproduce}
# The reference optimum of a figure (raico.thesis.claims.reference_cost): the lowest median final cost any solver
# reaches on the figure's initial states, including long-budget runs: the adaptive R-AICO at FDDP's budget, which
# every plan figure's file lists (crocoddyl FDDP at 100 iterations joins it on the analytic arm)
REFERENCE = next(v for v in EXPERIMENTS["fig3.2a"].variants if v.label == "R-AICO adaptive (a0=1)")
