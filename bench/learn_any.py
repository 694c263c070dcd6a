"""Learning a model file's mistakes: the UR5 with an unmodelled payload (``problems/examples/ur5_payload.toml``).

The file's UR5 plans; the robot that executes carries 1 kg at its tool and links 25 % heavier than the
file says (``[robot.true]``). Three rows: the plan on the model file alone (analytic dynamics) executed
on the true robot, and the learning loop (``raico learn --problem``) with the residual GP (model +
GP of what it misses) and with the full GP (the thesis's). Per episode: the executed distance to the
reach target, the GP's held-out error (babbling of another seed, rad/s^2), the training points and
the wall time of fit + plan + execute. One run, in a cache of its own (``--artifacts``, default
``artifacts/bench/learn_any``); the page is ``artifacts/bench/learn_any.md`` (+ ``.json``), which
``scripts/readme_numbers.py`` puts into the README.

    python -m bench.learn_any [--episodes 5] [--full-episodes 20] [--render]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = ROOT / "problems" / "examples" / "ur5_payload.toml"
# the learning loop's settings beyond raico learn's defaults (the same for both models)
LEARN = {"babble_points": 200, "babble_amplitude": 0.3, "alpha": 1.0, "iterations": 50, "seed": 0}
MISS = 0.03  # m: the model-file plan misses by more than this
REACH = 0.01  # m: the learning loop's goal


def model_file_row(cache) -> dict:
    """The plan on the model file alone, executed on the true robot: its distance to the target (m)."""
    from pipeline.runner import run
    from stages.execute import ExecuteConfig
    from stages.plan.stage import PlanConfig

    t0 = time.perf_counter()
    plan = run(cache, "plan", PlanConfig(problem=str(PROBLEM)), record=False)
    ex = run(cache, "execute", ExecuteConfig(plan=plan.key), record=False)
    errs = ex.metrics.get("via_point_errors") or {}
    return {"model": "model file only", "distance_m": [errs.get("reach@100")], "status": [ex.status],
            "wall_s": time.perf_counter() - t0}


def learn_row(cache, residual: bool, episodes: int) -> dict:
    """The learning loop with the residual or the full GP: per-episode numbers and the wall time."""
    from pipeline.runner import run
    from stages.learn import LearnConfig

    cfg = LearnConfig(problem=str(PROBLEM), residual=residual, episodes=episodes, **LEARN)
    t0 = time.perf_counter()
    out = run(cache, "learn", cfg, record=False)
    wall = time.perf_counter() - t0
    doc = json.loads((Path(out.path) / "episodes.json").read_text())
    eps = doc["episodes"]
    first = next((e["episode"] for e in eps if e["task_error"] <= REACH and e["execution_status"] == "ok"), None)
    return {"model": "residual GP" if residual else "full GP", "distance_m": [e["task_error"] for e in eps],
            "status": [e["execution_status"] for e in eps], "gp_error_heldout": [e.get("gp_error_heldout") for e in eps],
            "n_points": [e["n_points"] for e in eps],
            "episode_s": [sum(e.get(k) or 0.0 for k in ("fit_time_s", "plan_time_s", "execute_time_s")) for e in eps],
            "first_within_1cm": first, "wall_s": wall}


def page(rows: list[dict], load: str) -> str:
    """The markdown page: one table per row, distance per episode."""
    lines = [f"UR5 with an unmodelled 1 kg payload at the tool and links 25 % heavier than its file "
             f"(`problems/examples/ur5_payload.toml`); settings {LEARN}; load average {load}.", ""]
    for r in rows:
        lines.append(f"**{r['model']}** (wall {r['wall_s']:.0f} s"
                     + (f"; first episode within 1 cm: {r['first_within_1cm']}" if "first_within_1cm" in r else "")
                     + ")")
        lines += ["", "| episode | distance (cm) | execution | GP held-out error (rad/s^2) | points | time (s) |",
                  "|---|---|---|---|---|---|"]
        for k, d in enumerate(r["distance_m"]):
            gp = r.get("gp_error_heldout", [None] * (k + 1))[k]
            pts = r.get("n_points", [None] * (k + 1))[k]
            sec = r.get("episode_s", [None] * (k + 1))[k]
            lines.append(f"| {k + 1 if 'n_points' in r else '-'} | {100 * d:.2f} | {r['status'][k]} | "
                         f"{'' if gp is None else f'{gp:.3g}'} | {'' if pts is None else pts} | "
                         f"{'' if sec is None else f'{sec:.1f}'} |")
        lines.append("")
    return "\n".join(lines)


def plot(rows: list[dict], path: Path) -> None:
    """Distance to the target per episode (cm, log scale) of each learning loop, the model-file plan's as a
    line, the 1 cm goal dashed; and the GP's held-out error per episode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(10, 3.6))
    for r in rows:
        d = 100 * np.asarray(r["distance_m"], float)
        if "n_points" not in r:
            ax.axhline(d[0], color="k", lw=1.2, label=f"{r['model']} ({d[0]:.2f} cm)")
            continue
        k = np.arange(1, len(d) + 1)
        ax.plot(k, d, "o-", label=r["model"])
        ax2.plot(k, np.asarray(r["gp_error_heldout"], float), "o-", label=r["model"])
    ax.axhline(100 * REACH, color="g", ls="--", lw=1, label="1 cm")
    ax.set(yscale="log", xlabel="episode", ylabel="executed distance to the target (cm)",
           title="UR5, 1 kg unmodelled payload")
    ax2.set(yscale="log", xlabel="episode", ylabel="GP held-out error (rad/s^2)", title="model error")
    ax.legend(fontsize=8)
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    import os

    from pipeline.cache import Cache

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=5, help="episodes of the residual-GP loop")
    ap.add_argument("--full-episodes", type=int, default=20, help="episodes of the full-GP loop (0: skip it)")
    ap.add_argument("--artifacts", default=str(ROOT / "artifacts"))
    ap.add_argument("--render", action="store_true", help="only write the page and plot again from learn_any.json")
    args = ap.parse_args()
    out = Path(args.artifacts) / "bench"
    if args.render:
        doc = json.loads((out / "learn_any.json").read_text())
        (out / "learn_any.md").write_text(page(doc["rows"], doc["load"]))
        plot(doc["rows"], out / "learn_any.png")
        return
    cache = Cache(out / "learn_any")
    rows = [model_file_row(cache), learn_row(cache, True, args.episodes)]
    if args.full_episodes:
        rows.append(learn_row(cache, False, args.full_episodes))
    load = " ".join(f"{v:.2f}" for v in os.getloadavg())
    out.mkdir(parents=True, exist_ok=True)
    (out / "learn_any.json").write_text(json.dumps({"rows": rows, "settings": LEARN, "load": load}, indent=1))
    (out / "learn_any.md").write_text(page(rows, load))
    plot(rows, out / "learn_any.png")
    print(page(rows, load))


if __name__ == "__main__":
    main()
