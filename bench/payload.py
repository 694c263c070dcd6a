"""A payload that needs learning: the UR5 with 5 kg at its tool that its model file does not know.

``experiments/ur5_payload_5kg.toml`` (its problem: ``raico/problems/examples/ur5_payload_5kg.toml``). Rows: the
model file's plan executed on the true robot (one run: no seed enters it), and per variant of the experiment
file (without and with the uncertainty term) the residual-GP loop over ``SEEDS`` seeds with the planner a
problem file gets by default (R-AICO's robust schedule, hard bounds). Per seed and episode: the executed distance
to the reach target, the execution's status, the GP's error on that episode's execution (a prediction: the
execution joins only the next fit) and on the held-out babbling (another seed), the training points and the fit
and plan wall times. The target: within 1 cm after at most 2 episodes in >= 9 of 10 seeds, each episode's
fit + plan <= 10 s. One run, in a cache of its own; the page is ``artifacts/bench/payload.md`` (+ ``.json``,
``.png``: the executed distance per episode).

    python -m bench.payload [--seeds 10] [--jobs 2] [--render]
"""

from __future__ import annotations

import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from bench import baseline_learn
from bench.learning_common import episode_axes, load_text, parser

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENT = ROOT / "experiments" / "ur5_payload_5kg.toml"
REACH = 0.01        # m: the goal
EPISODES_TARGET = 2  # within REACH after at most this many episodes
BUDGET_S = 10.0     # s: fit + plan per episode
REACH_TERM, LEVEL_TERM = "reach@100", "level@max"   # the problem's via-point terms: the tool's position at the
# end (m) and its orientation's worst error over the motion (rad): an episode's task verdict names the worse one


def variants() -> tuple[dict, list[dict]]:
    """The experiment file's ``[base]`` and its points (:func:`bench.learning_common.experiment_points`)."""
    from bench.learning_common import experiment_points

    return experiment_points(EXPERIMENT)


def model_file_row(artifacts: str) -> dict:
    """The model file's plan (analytic dynamics, the file's robot) executed on the true robot."""
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.runner import run
    from raico.stages.execute.config import ExecuteConfig
    from raico.stages.plan.stage import PlanConfig

    base, _ = variants()
    cache = Cache(Path(artifacts) / "bench" / "payload")
    plan = run(cache, "plan", PlanConfig(problem=base["problem"]), record=False)
    ex = run(cache, "execute", ExecuteConfig(plan=plan.key), record=False)
    return {"planned_m": plan.metrics["via_point_errors"][REACH_TERM],
            "executed_m": ex.metrics["via_point_errors"][REACH_TERM],
            "executed_level_rad": ex.metrics["via_point_errors"][LEVEL_TERM], "status": ex.status}


def run_seed(job: tuple[str, int, dict]) -> dict:
    """One seed's loop of one variant: per-episode numbers (``raico.stages.learn``'s episodes.json)."""
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.runner import run
    from raico.stages.learn import LearnConfig

    artifacts, seed, point = job
    base, _ = variants()
    over = {k: v for k, v in point.items() if k != "label"}
    cache = Cache(Path(artifacts) / "bench" / "payload")
    t0 = time.perf_counter()
    out = run(cache, "learn", LearnConfig(**{**base, **over, "seed": seed}), record=False)
    eps = json.loads((Path(out.path) / "episodes.json").read_text())["episodes"]
    errs = [cache.require("execute", e["execute"]).metrics["via_point_errors"] for e in eps]
    planned = [cache.require("plan", e["plan"]).metrics["via_point_errors"] for e in eps]
    return {"label": point["label"], "seed": seed, "wall_s": time.perf_counter() - t0,
            "distance_m": [v[REACH_TERM] for v in errs], "level_rad": [v[LEVEL_TERM] for v in errs],
            "planned_distance_m": [v[REACH_TERM] for v in planned], "achieved": [e["achieved"] for e in eps],
            "status": [e["execution_status"] for e in eps],
            "plan_status": [e["plan_status"] for e in eps],
            "gp_error": [e["gp_error"] for e in eps], "gp_error_heldout": [e["gp_error_heldout"] for e in eps],
            "n_points": [e["n_points"] for e in eps], "data_steps": [e["data_steps"] for e in eps],
            "fit_s": [e["fit_time_s"] for e in eps], "plan_s": [e["plan_time_s"] for e in eps]}


def first_within(r: dict) -> int | None:
    """The first episode whose execution was ok and ended within ``REACH`` (None: none)."""
    return next((k + 1 for k, (d, s) in enumerate(zip(r["distance_m"], r["status"])) if d <= REACH and s == "ok"),
                None)


def medians(rs: list[dict], key: str, scale: float = 1.0) -> str:
    """Per episode, the median over the seeds' runs ``rs`` of ``key`` (times ``scale``), joined by slashes."""
    return " / ".join(f"{scale * v:.3g}" for v in np.median([r[key] for r in rs], 0))


def counts(rs: list[dict], key: str) -> str:
    """How often each status of ``key`` occurs over all episodes of the runs ``rs``."""
    from collections import Counter

    return ", ".join(f"{k} {v}" for k, v in sorted(Counter(x for r in rs for x in r[key]).items()))


def page(doc: dict) -> str:
    """The markdown page: the model file's miss, one summary row per variant, per-episode medians, per seed."""
    mf, runs = doc["model_file"], doc["runs"]
    labels = list(dict.fromkeys(r["label"] for r in runs))
    lines = [f"UR5 carrying an unmodelled 5 kg at the tool (`raico/problems/examples/ur5_payload_5kg.toml`); the loop "
             f"of `experiments/ur5_payload_5kg.toml` ({doc['settings']}), the planner's defaults for a problem file "
             f"(R-AICO's robust schedule, hard bounds); {doc['seeds']} seeds; load average {doc['load']} (2 cores "
             "shared: times under load).", "",
             f"Model file's plan executed on the true robot: {100 * mf['executed_m']:.2f} cm from the target "
             f"(planned {100 * mf['planned_m']:.2f} cm; tool orientation {mf['executed_level_rad']:.3f} rad off at "
             f"worst; execution {mf['status']}).", "",
             f"| uncertainty term | seeds within 1 cm by episode {EPISODES_TARGET} | first within 1 cm (median) | "
             "executed distance per episode, median (cm) | planned distance, median (cm) | tool orientation error "
             "executed, median (rad) | task achieved (both terms) | GP error on the next execution, median "
             "(rad/s^2) | GP held-out error, median (rad/s^2) | fit + plan per episode, median / max (s) | "
             "execution statuses | plan statuses |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for lab in labels:
        rs = [r for r in runs if r["label"] == lab]
        firsts = [first_within(r) for r in rs]
        hit = sum(f is not None and f <= EPISODES_TARGET for f in firsts)
        reached = [f for f in firsts if f is not None]
        fp = [a + b for r in rs for a, b in zip(r["fit_s"], r["plan_s"])]
        n = sum(len(r["status"]) for r in rs)
        achieved = sum(a for r in rs for a in r["achieved"])
        lines.append(f"| {lab} | {hit} of {len(rs)} | {f'{np.median(reached):g}' if reached else 'none'} | "
                     f"{medians(rs, 'distance_m', 100)} | {medians(rs, 'planned_distance_m', 100)} | "
                     f"{medians(rs, 'level_rad')} | {achieved} of {n} | {medians(rs, 'gp_error')} | "
                     f"{medians(rs, 'gp_error_heldout')} | {np.median(fp):.1f} / {max(fp):.1f} | "
                     f"{counts(rs, 'status')} | {counts(rs, 'plan_status')} |")
    if doc.get("baseline") and "payload" in doc["baseline"]:   # a learner that is not raico, from bench.baseline_learn
        lines.append(baseline_learn.payload_row(doc["baseline"]))
    lines += ["", "Per seed: executed distance per episode (cm), training points per episode, fit + plan per "
              "episode (s).", "", "| uncertainty term | seed | distance (cm) | points | fit + plan (s) | statuses |",
              "|---|---|---|---|---|---|"]
    for r in runs:
        lines.append(f"| {r['label']} | {r['seed']} | {' '.join(f'{100 * d:.2f}' for d in r['distance_m'])} | "
                     f"{' '.join(str(p) for p in r['n_points'])} | "
                     f"{' '.join(f'{a + b:.1f}' for a, b in zip(r['fit_s'], r['plan_s']))} | "
                     f"{' '.join(sorted(set(r['status'])))} |")
    return "\n".join(lines) + "\n"


def plot(doc: dict, path: Path) -> None:
    """Executed distance per episode (cm, log): each seed thin, the median thick, per variant; the model file's
    miss and the 1 cm goal as lines. Right: the GP's error on the next execution and on the held-out babbling."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    runs = doc["runs"]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 4.4))
    for i, lab in enumerate(dict.fromkeys(r["label"] for r in runs)):
        rs = [r for r in runs if r["label"] == lab]
        c = f"C{i}"
        D = 100 * np.array([r["distance_m"] for r in rs], float)
        k = np.arange(1, D.shape[1] + 1)
        for d in D:
            ax.plot(k, d, "-", color=c, lw=0.6, alpha=0.4)
        ax.plot(k, np.median(D, 0), "o-", color=c, lw=2, label=f"{lab} (median of {len(rs)} seeds)")
        ax2.plot(k, np.median([r["gp_error"] for r in rs], 0), "o-", color=c, label=f"{lab}: next execution")
        ax2.plot(k, np.median([r["gp_error_heldout"] for r in rs], 0), "s--", color=c,
                 label=f"{lab}: held-out babbling")
    ax.axhline(100 * doc["model_file"]["executed_m"], color="k", lw=1.2,
               label=f"model file's plan ({100 * doc['model_file']['executed_m']:.1f} cm)")
    ax.axhline(100 * REACH, color="g", ls="--", lw=1, label="1 cm")
    ax.set(yscale="log", xlabel="episode", ylabel="executed distance to the target (cm)",
           title="UR5, 5 kg unmodelled payload: residual GP")
    ax2.set(yscale="log", xlabel="episode", ylabel="GP error (rad/s^2), median", title="model error")
    episode_axes((ax, ax2), fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = parser(__doc__.splitlines()[0], "payload.json")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--jobs", type=int, default=2, help="loops run at once (processes)")
    args = ap.parse_args()
    out = Path(args.artifacts) / "bench"
    out.mkdir(parents=True, exist_ok=True)
    if not args.render:
        base, points = variants()
        mf = model_file_row(args.artifacts)
        jobs = [(args.artifacts, s, p) for s in range(args.seeds) for p in points]
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            runs = list(pool.map(run_seed, jobs))
        settings = {k: v for k, v in base.items() if k != "problem"}
        load = load_text()
        (out / "payload.json").write_text(json.dumps({"model_file": mf, "runs": runs, "settings": settings,
                                                      "seeds": args.seeds, "load": load}, indent=1))
    doc = json.loads((out / "payload.json").read_text())
    doc["baseline"] = baseline_learn.load_doc(args.artifacts)
    (out / "payload.md").write_text(page(doc))
    plot(doc, out / "payload.png")
    print(page(doc))


if __name__ == "__main__":
    main()
