"""Experiments of SPEC §10 (thesis figs. 3.2-3.4): definitions, the parallel sweep, figure, claims.

An experiment is a set of plan runs: every solver variant on every initial state
``q0 = default + N(0, 0.05^2)`` (seeds 0..9). Each run is a cached plan artifact, so a second
call is served from the cache. For the Nao figures the R-AICO plans are also executed in
Drake (CoG against the support polygon). ``--quick`` uses 2 seeds and fewer iterations.
"""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from pipeline.cache import Cache
from pipeline.runner import Outcome


@dataclass(frozen=True)
class Variant:
    solver: str
    alpha: float = 0.0
    relinearize: bool = True  # AICO only: False is the ablation without sweep relinearization

    @property
    def label(self) -> str:
        base = {"ilqg": "iLQG", "aico": "AICO"}.get(self.solver, f"R-AICO a={self.alpha:g}")
        return base if self.relinearize else f"{base} (no sweep relinearization)"


@dataclass(frozen=True)
class Experiment:
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


ARM_VARIANTS = (Variant("ilqg"), Variant("aico"), Variant("raico", 1.0), Variant("raico", 10.0))
ABLATION = Variant("aico", 0.0, relinearize=False)
EXPERIMENTS: dict[str, Experiment] = {
    "fig3.2a": Experiment("fig3.2a", "arm5", "reach", "pseudo", ARM_VARIANTS, 40, 6,
                          "arm5, pseudo-dynamics, via-points (1,-0.4,0)@500 and (1,0,0)@1000",
                          claims=("raico_converges", "all_converge_aico_fastest")),
    "fig3.2b": Experiment("fig3.2b", "arm5", "reach-roll", "pseudo", (*ARM_VARIANTS, ABLATION), 40, 6,
                          "as a, plus the roll angle at pi/2 (with an AICO ablation: no sweep relinearization)",
                          claims=("raico_converges", "aico_unstable", "aico_unstable_without_relinearization")),
    "fig3.2c": Experiment("fig3.2c", "arm5", "reach", "analytic", ARM_VARIANTS, 25, 4,
                          "as a, analytic Drake dynamics (controls = torques)",
                          claims=("raico_converges", "aico_fails", "ilqg_stalls")),
    "fig3.2d": Experiment("fig3.2d", "arm5", "reach-roll", "analytic", ARM_VARIANTS, 25, 4,
                          "as b, analytic Drake dynamics",
                          claims=("raico_converges", "aico_fails", "ilqg_stalls")),
    "fig3.3": Experiment("fig3.3", "nao", "reach", "pseudo",
                         (Variant("ilqg"), Variant("aico"), Variant("raico", 1.0)), 25, 5,
                         "Nao, pseudo-dynamics: right hand to a target, CoG held",
                         execute=(Variant("raico", 1.0),), claims=("raico_reaches_aico_not", "cog_support")),
    "fig3.4": Experiment("fig3.4", "nao", "balance", "pseudo",
                         (Variant("ilqg"), Variant("aico"), Variant("raico", 1.0), Variant("raico", 10.0)),
                         25, 5, "Nao, pseudo-dynamics: CoG 0.1 m right, left, back",
                         execute=(Variant("raico", 1.0),),
                         claims=("raico_reaches_aico_not", "raico_converges", "cog_support")),
    "fig3.4-inside": Experiment("fig3.4-inside", "nao", "balance-inside", "pseudo",
                                (Variant("aico"), Variant("raico", 1.0)), 25, 5,
                                "variant of 3.4 whose CoG offsets stay over the feet",
                                execute=(Variant("raico", 1.0),), claims=("cog_support",)),
}


def plan_config(exp: Experiment, v: Variant, seed: int, quick: bool):
    from stages.plan.stage import PlanConfig

    return PlanConfig(plant=exp.plant, task=exp.task, dynamics=exp.dynamics, solver=v.solver,
                      alpha=v.alpha if v.solver == "raico" else 1.0, gamma=1.0,
                      iterations=exp.quick_iterations if quick else exp.iterations, seed=seed,
                      q0_std=0.05, relinearize=v.relinearize).normalized()


def _job(args) -> dict:
    """One stage run in a worker process: ``(root, stage, config, record) -> Outcome fields``."""
    root, stage, cfg, record = args
    from pipeline import runner

    return runner.run(Cache(root), stage, cfg, record=record).__dict__


def _map(jobs: list, workers: int, progress: Callable[[int, int], None] | None) -> list[Outcome]:
    """Run ``jobs`` (``(root, stage, config, record)``): cached ones looked up here, the others in
    ``workers`` processes (none are started when everything is cached)."""
    from pipeline import runner

    results: list[Outcome | None] = [runner.lookup(Cache(j[0]), j[1], j[2], record=j[3]) for j in jobs]
    todo = [i for i, r in enumerate(results) if r is None]
    done = len(jobs) - len(todo)
    if progress and done:
        progress(done, len(jobs))
    if workers <= 1 or len(todo) <= 1:
        for i in todo:
            results[i] = Outcome(**_job(jobs[i]))
            done += 1
            if progress:
                progress(done, len(jobs))
        return results  # type: ignore[return-value]
    from concurrent.futures import as_completed

    with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")) as pool:
        futures = {pool.submit(_job, jobs[i]): i for i in todo}
        for f in as_completed(futures):
            results[futures[f]] = Outcome(**f.result())
            done += 1
            if progress:
                progress(done, len(jobs))
    return results  # type: ignore[return-value]


def run_experiment(cache: Cache, exp: Experiment, quick: bool = False, workers: int = 2,
                   record: bool = True, progress=None) -> dict:
    """All runs of ``exp`` (cached per run): plans, then the executions of the chosen variants."""
    from stages.execute import ExecuteConfig

    seeds = range(2 if quick else exp.seeds)
    runs = [(v, s, plan_config(exp, v, s, quick)) for v in exp.variants for s in seeds]
    root = str(cache.root)
    outs = _map([(root, "plan", cfg, record) for _, _, cfg in runs], workers, progress)
    plans = [{"variant": v, "seed": s, "outcome": o} for (v, s, _), o in zip(runs, outs)]
    ex_jobs = [(root, "execute", ExecuteConfig(plan=f"plan/{p['outcome'].key}"), record)
               for p in plans if p["variant"] in exp.execute]
    executions = _map(ex_jobs, workers, None)
    return {"plans": plans, "executions": executions}


# ----------------------------------------------------------------------------- analysis
def cost_curves(cache: Cache, plans: list[dict], variant: Variant, what: str = "costs") -> np.ndarray:
    """``(seeds, iterations)`` per-iteration ``what`` (``costs`` or ``elapsed`` wall time, s) of a
    variant's runs; runs that stopped early hold their last value, diverged runs are NaN after
    they diverged."""
    from pipeline.runner import as_artifact

    curves = []
    for p in plans:
        if p["variant"] != variant:
            continue
        d = as_artifact(cache.require("plan", p["outcome"].key)).arrays("plan.npz")
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


def summarize(plans: list[dict], variant: Variant) -> dict:
    """The variant's summary (``stages.evaluate.summary``) over its runs."""
    from stages.evaluate.summary import summarize as summary

    return summary(variant.label, [{"status": p["outcome"].status, "metrics": p["outcome"].metrics}
                                   for p in plans if p["variant"] == variant])


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


def _sigma_settings() -> tuple[LearnSetting, ...]:
    out = []
    for w in (1e-2, 1e2):
        for sigma in ("0", "0.2", "1"):
            seeds = 5 if (sigma, w) == ("0", 1e-2) else 2  # five seeds for the data-efficiency comparison
            out.append(LearnSetting(f"sigma*={sigma}, w={w:g}", (("sigma_star", sigma), ("sigma_weight", w)), seeds,
                                    quick=(sigma, w) in (("0", 1e-2), ("1", 1e2))))
    out.append(LearnSetting("sigma*=none", (("sigma_star", "none"),), 2, quick=True))
    return tuple(out)


LEARN_EXPERIMENTS: dict[str, LearnExperiment] = {
    "fig4.1/4.2": LearnExperiment(
        "fig4.1/4.2", "pendulum", "swing-up",
        "pendulum swing-up on a GP model learned while planning: sigma* in {0, 0.2, 1, none}, w in {1e-2, 1e2}",
        _sigma_settings(), (("alpha", 0.0), ("babble_points", 15), ("iterations", 20), ("max_points", 600),
                            ("restarts", 1), ("stride", 5)), episodes=10, quick_episodes=6,
        claims=("gp_error_falls", "rmse_falls", "large_weight_explores", "swing_up_achieved", "pilco_efficiency"),
        notes=(("pendulum learning horizon", "1.5 s at 2 ms (750 steps): the thesis's 300 ms cannot swing up under "
                "+-10 N m; swing-up counted when the executed pendulum ends within 0.1 rad of upright"),
               ("babbling", "15 samples, one every 0.1 s of PD tracking (Kp 50, Kd 5) of a random spline, "
                "amplitude 1 rad"),
               ("GP data", "every 5th executed step joins the training set; at most 600 points (recent half "
                "plus farthest-point subsample of the rest)"),
               ("uncertainty term", "g = GP latent variance in units of the training outputs' variance; "
                "state-control cross terms dropped"))),
    "fig4.3": LearnExperiment(
        "fig4.3", "biorob", "reach",
        "BioRob-like arm reaching x0 + (0.5, 0, 0.5) m in 1 s on a GP model: hyperparameter schedules every vs "
        "batch-100, 20 evaluations warm-started",
        (LearnSetting("every", (("schedule", "every"),), 1, quick=True),
         LearnSetting("batch-100", (("schedule", "batch-100"),), 1, quick=True)),
        (("alpha", 2.0), ("babble_points", 100), ("iterations", 10), ("max_points", 300), ("restarts", 0),
         ("stride", 20), ("sigma_star", "none")), episodes=20, quick_episodes=3,
        claims=("batch_cheaper", "reach_achieved"),
        notes=(("biorob learning", "100 babbling samples (10 s); every 20th executed step joins the data (25 per "
                "evaluation); at most 300 training points; no optimizer restarts; 10 R-AICO iterations per "
                "evaluation, warm-started from the previous plan"),)),
}


def learn_config(exp: LearnExperiment, s: LearnSetting, seed: int, quick: bool):
    from stages.learn import LearnConfig

    return LearnConfig(plant=exp.plant, task=exp.task, **dict(exp.base), **dict(s.overrides), seed=seed,
                       episodes=exp.quick_episodes if quick else exp.episodes)


def _learn_job(args) -> dict:
    root, cfg, record = args
    from pipeline.learn import learn

    return learn(Cache(root), cfg, record=record).__dict__


def run_learn_experiment(cache: Cache, exp: LearnExperiment, quick: bool = False, workers: int = 2,
                         record: bool = True, progress=None) -> dict:
    """Every setting's learning loops (cached per loop, and per stage run inside)."""
    from pipeline.learn import lookup

    runs = [(s, k, learn_config(exp, s, k, quick)) for s in exp.settings if s.quick or not quick
            for k in range(1 if quick else s.seeds)]
    jobs = [(str(cache.root), cfg, record) for _, _, cfg in runs]
    results: list = [lookup(cache, cfg, record=record) for _, _, cfg in runs]
    todo = [i for i, r in enumerate(results) if r is None]
    done = len(runs) - len(todo)
    if progress:
        progress(done, len(runs))
    if workers <= 1 or len(todo) <= 1:
        for i in todo:
            results[i] = Outcome(**_learn_job(jobs[i]))
            done += 1
            if progress:
                progress(done, len(runs))
    else:
        from concurrent.futures import as_completed

        with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")) as pool:
            futures = {pool.submit(_learn_job, jobs[i]): i for i in todo}
            for f in as_completed(futures):
                results[futures[f]] = Outcome(**f.result())
                done += 1
                if progress:
                    progress(done, len(runs))
    return {"learns": [{"setting": s, "seed": k, "outcome": o} for (s, k, _), o in zip(runs, results)]}


def summarize_learns(learns: list[dict]) -> dict[str, dict]:
    """Setting label -> ``stages.evaluate.summary.summarize_learn`` over its seeds."""
    from stages.evaluate.summary import summarize_learn

    labels = list(dict.fromkeys(x["setting"].label for x in learns))
    return {lab: summarize_learn(lab, [x["outcome"].metrics for x in learns if x["setting"].label == lab])
            for lab in labels}
