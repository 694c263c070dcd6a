"""One learning episode of fig4.3 (BioRob-like arm, learned GP dynamics), split into its stages.

The learning loop's first episode after babbling, timed per stage from a fresh cache: fit (GP
hyperparameters by maximum likelihood), plan (R-AICO on the GP model) and execute (Drake's
Simulator). Wall seconds of each stage's compute, as the cache records them; one run (the fit
dominates and is deterministic in cost), in a temporary folder.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path


def bench_learn_episode() -> dict:
    """``{"fit_s", "plan_s", "execute_s", "n_points"}`` of episode 1 of fig4.3's ``every`` setting."""
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.runner import run
    from raico.thesis.figures import LEARN_EXPERIMENTS, learn_config

    exp = LEARN_EXPERIMENTS["fig4.3"]
    cfg = learn_config(exp, exp.settings[0], 0, quick=True)
    cfg = type(cfg)(**{**cfg.to_dict(), "episodes": 1})
    with tempfile.TemporaryDirectory() as tmp:
        out = run(Cache(tmp), "learn", cfg, record=False)
        doc = json.loads((Path(out.path) / "episodes.json").read_text())
        ep = doc["episodes"][0]
        t = {stage: json.loads((Path(tmp) / stage / ep[stage] / "meta.json").read_text())["timings"]["compute_s"]
             for stage in ("fit", "plan", "execute")}
    return {"fit_s": t["fit"], "plan_s": t["plan"], "execute_s": t["execute"], "n_points": ep["n_points"]}


def bench_learn_default(episodes: int = 20, seed: int = 0) -> dict:
    """The whole ``raico learn --plant biorob --task reach --episodes 20 --alpha 2`` with every other
    option at its default (target 60 s), from a fresh cache: ``{"wall_s", "task_error_last",
    "status_last", "n_points_last"}``."""
    import time

    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.runner import run
    from raico.stages.learn import LearnConfig

    cfg = LearnConfig(plant="biorob", task="reach", episodes=episodes, alpha=2.0, seed=seed)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        out = run(Cache(tmp), "learn", cfg, record=False)
        wall = time.perf_counter() - t0
    m = out.metrics
    return {"wall_s": wall, "task_error_last": m["task_error"][-1], "status_last": m["execution_status"][-1],
            "n_points_last": m["n_points"][-1]}


def bench_learn_evaluation(gp: str = "exact", inducing: int = 200, points: int = 1000, seed: int = 0) -> dict:
    """One fig4.3 evaluation (fit + plan + execute) at ``points`` training points (target
    1.0 s), with the exact or the sparse GP (``inducing`` points), from a fresh cache.

    fig4.3's ``every`` setting with 250 babbling points (the babbling allows at most 100 spline
    knots, i.e. about 250 points), every 2nd executed step as data (``stride`` 2: 250 points per
    full 500-step execution; fig4.3 uses 20) and ``points / 250`` episodes: the last one, the one
    timed, fits on ``points`` points when every execution ran to its end, as the loop does after
    its first fit: hyperparameters re-optimized by L-BFGS-B warm-started at the previous fit's, no
    random restarts (``refit_restarts`` 0, schedule ``every``), then 10 R-AICO iterations on the GP
    and the execution in Drake. The first fit is set to 0 restarts here (it is not timed).
    Returns ``{"fit_s", "plan_s", "execute_s", "total_s", "n_points", "gp", "n_inducing"}``."""
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.runner import run
    from raico.thesis.figures import LEARN_EXPERIMENTS, learn_config

    exp = LEARN_EXPERIMENTS["fig4.3"]
    cfg = learn_config(exp, exp.settings[0], seed, quick=True)
    cfg = type(cfg)(**{**cfg.to_dict(), "episodes": max(1, points // 250), "babble_points": 250, "stride": 2,
                       "restarts": 0, "gp": gp, "inducing": inducing, "max_points": max(cfg.max_points, points)})
    with tempfile.TemporaryDirectory() as tmp:
        out = run(Cache(tmp), "learn", cfg, record=False)
        ep = json.loads((Path(out.path) / "episodes.json").read_text())["episodes"][-1]
        t = {stage: json.loads((Path(tmp) / stage / ep[stage] / "meta.json").read_text())["timings"]["compute_s"]
             for stage in ("fit", "plan", "execute")}
        fit_doc = json.loads((Path(tmp) / "fit" / ep["fit"] / "fit.json").read_text())
    return {"fit_s": t["fit"], "plan_s": t["plan"], "execute_s": t["execute"],
            "total_s": t["fit"] + t["plan"] + t["execute"], "n_points": ep["n_points"], "gp": gp,
            "n_inducing": fit_doc.get("n_inducing"), "fit_mode": fit_doc["mode"],
            "task_error": ep["task_error"], "execution_status": ep["execution_status"]}


if __name__ == "__main__":
    import sys

    if len(sys.argv) > 1 and sys.argv[1] in ("exact", "sparse"):  # python -m bench.learn_bench sparse [M]
        print(json.dumps(bench_learn_evaluation(sys.argv[1], *map(int, sys.argv[2:3])), indent=2))
    else:
        print(json.dumps(bench_learn_episode(), indent=2))
