"""Experiments of SPEC §10 (thesis figs. 3.2-3.4): definitions, the parallel sweep, figure, claims.

An experiment is a set of plan runs: every solver variant on every initial state
``q0 = default + N(0, 0.05^2)`` (seeds 0..9). Each run is a cached plan artifact, so a second
call is served from the cache. For the Nao figures the R-AICO plans are also executed in
Drake (CoG against the support polygon). ``--quick`` uses 2 seeds and fewer iterations.
"""

from __future__ import annotations

import math
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


def _plan_job(args) -> dict:
    root, cfg, record = args
    from pipeline import stage_io

    out = stage_io.run_plan(Cache(root), cfg, record=record)
    return out.__dict__


def _execute_job(args) -> dict:
    root, key, record = args
    from pipeline import stage_io
    from stages.execute import ExecuteConfig

    return stage_io.run_execute(Cache(root), f"plan/{key}", ExecuteConfig(), record=record).__dict__


def _map(fn, jobs: list, workers: int, progress: Callable[[int, int], None] | None) -> list:
    if workers <= 1 or len(jobs) <= 1:
        out = []
        for i, j in enumerate(jobs):
            out.append(fn(j))
            if progress:
                progress(i + 1, len(jobs))
        return out
    results = [None] * len(jobs)
    with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")) as pool:
        futures = {pool.submit(fn, j): i for i, j in enumerate(jobs)}
        from concurrent.futures import as_completed

        for done, f in enumerate(as_completed(futures), 1):
            results[futures[f]] = f.result()
            if progress:
                progress(done, len(jobs))
    return results


def run_experiment(cache: Cache, exp: Experiment, quick: bool = False, workers: int = 2,
                   record: bool = True, progress=None) -> dict:
    """All runs of ``exp`` (cached per run), then the figure and the claims table in ``out_dir``."""
    seeds = range(2 if quick else exp.seeds)
    runs = [(v, s, plan_config(exp, v, s, quick)) for v in exp.variants for s in seeds]
    outs = _map(_plan_job, [(str(cache.root), cfg, record) for _, _, cfg in runs], workers, progress)
    plans = [{"variant": v, "seed": s, "outcome": Outcome(**o)} for (v, s, _), o in zip(runs, outs)]
    ex_jobs = [(str(cache.root), p["outcome"].key, record) for p in plans if p["variant"] in exp.execute]
    ex_outs = _map(_execute_job, ex_jobs, workers, None)
    executions = [Outcome(**o) for o in ex_outs]
    return {"plans": plans, "executions": executions}


# ----------------------------------------------------------------------------- analysis
def cost_curves(cache: Cache, plans: list[dict], variant: Variant) -> np.ndarray:
    """``(seeds, iterations)`` cost per iteration; runs that stopped early hold their last cost,
    diverged runs are NaN after they diverged."""
    from pipeline.stage_io import load_npz

    curves = []
    for p in plans:
        if p["variant"] != variant:
            continue
        entry = cache.require("plan", p["outcome"].key)
        c = load_npz(entry, "plan.npz")["costs"].astype(float)
        curves.append(c)
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
    ms = [p["outcome"].metrics for p in plans if p["variant"] == variant]
    st = [p["outcome"].status for p in plans if p["variant"] == variant]
    ratio = np.array([m.get("cost_ratio") if m.get("cost_ratio") is not None else np.nan for m in ms], float)
    final = np.array([m.get("final_cost", np.nan) for m in ms], float)
    first = np.array([m.get("first_iteration_cost", np.nan) for m in ms], float)
    via = [max(m.get("via_point_errors", {}).get(k, 0.0) for k in m.get("via_point_errors", {}) if
               not k.startswith("r_sole")) if m.get("via_point_errors") else np.nan for m in ms]
    return {"label": variant.label, "runs": len(ms), "diverged": st.count("diverged"),
            "converged": st.count("converged"), "final_cost_median": _med(final),
            "first_cost_median": _med(first), "cost_ratio_median": _med(ratio),
            "cost_ratio_max": float(np.nanmax(ratio)) if np.isfinite(ratio).any() else math.nan,
            "final_cost_max": float(np.nanmax(final)) if np.isfinite(final).any() else math.inf,
            "max_via_error_median": _med(np.array(via, float)),
            "wall_time_median_s": _med(np.array([m.get("wall_time_s", np.nan) for m in ms], float))}


def _med(a: np.ndarray) -> float:
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else math.nan
