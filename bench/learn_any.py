"""Learning a model file's mistakes: the UR5 with an unmodelled payload (``raico/problems/examples/ur5_payload.toml``).

The file's UR5 plans; the robot that executes carries 1 kg at its tool and links 25 % heavier than the
file says (``[robot.true]``). Rows: the plan on the model file alone (analytic dynamics) executed
on the true robot, and the learning loop (``raico learn --problem``) with the residual GP (model +
GP of what it misses) and with the full GP (the thesis's), each without and with the uncertainty term
(thesis eq. 4.3, ``sigma* = 0``, weights ``SIGMA_WEIGHTS`` in standardized units). Per episode: the
executed distance to the reach target, the GP's held-out error (babbling of another seed, rad/s^2), the training points and
the wall time of fit + plan + execute. One run, in a cache of its own (``--artifacts``, default
``artifacts/bench/learn_any``); the page is ``artifacts/bench/learn_any.md`` (+ ``.json``), which
``scripts/readme_numbers.py`` puts into docs/learning.md.

    python -m bench.learn_any [--episodes 5] [--full-episodes 20] [--render]
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from bench.learning_common import episode_axes, load_text, parser

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = ROOT / "raico" / "problems" / "examples" / "ur5_payload.toml"
# the learning loop's settings beyond raico learn's defaults (the same for both models): R-AICO with the
# thesis's fixed alpha, as in its learning experiments (a problem file's default is the robust schedule)
LEARN = {"babble_points": 200, "babble_amplitude": 0.3, "alpha": 1.0, "alpha_schedule": "fixed", "iterations": 50,
         "seed": 0}
SIGMA_WEIGHTS = (None, 1e-2, 1.0)  # the uncertainty term's weights (None: no term), sigma* = 0, standardized
REACH = 0.01  # m: the learning loop's goal
REACH_TERM = "reach@100"  # the problem's via-point term of the tool's position at the end


def model_file_row(cache) -> dict:
    """The plan on the model file alone, executed on the true robot: its distance to the target (m)."""
    from raico.pipeline.engine.runner import run
    from raico.stages.execute.config import ExecuteConfig
    from raico.stages.plan.stage import PlanConfig

    t0 = time.perf_counter()
    plan = run(cache, "plan", PlanConfig(problem=str(PROBLEM)), record=False)
    ex = run(cache, "execute", ExecuteConfig(plan=plan.key), record=False)
    errs = ex.metrics.get("via_point_errors") or {}
    return {"model": "model file only", "distance_m": [errs.get(REACH_TERM)], "status": [ex.status],
            "wall_s": time.perf_counter() - t0}


def learn_row(cache, residual: bool, episodes: int, sigma_weight: float | None = None) -> dict:
    """The learning loop with the residual or the full GP, with the uncertainty term (``sigma* = 0``,
    weight ``sigma_weight``, standardized units) or without (None): per-episode numbers and the wall time."""
    from raico.pipeline.engine.runner import run
    from raico.stages.learn import LearnConfig

    sigma = {} if sigma_weight is None else {"sigma_star": "0", "sigma_weight": sigma_weight,
                                              "sigma_units": "standardized"}
    cfg = LearnConfig(problem=str(PROBLEM), residual=residual, episodes=episodes, **LEARN, **sigma)
    t0 = time.perf_counter()
    out = run(cache, "learn", cfg, record=False)
    wall = time.perf_counter() - t0
    doc = json.loads((Path(out.path) / "episodes.json").read_text())
    eps = doc["episodes"]
    # the reach term's executed error (m), from each execution: an episode's task_error is its verdict's worst
    # term, which may be the orientation's (rad)
    dist = [cache.require("execute", e["execute"]).metrics["via_point_errors"][REACH_TERM] for e in eps]
    first = next((e["episode"] for e, d in zip(eps, dist) if d <= REACH and e["execution_status"] == "ok"), None)
    return {"model": "residual GP" if residual else "full GP",
            "uncertainty": "none" if sigma_weight is None else f"w = {sigma_weight:g}",
            "distance_m": dist, "status": [e["execution_status"] for e in eps],
            "gp_error_heldout": [e.get("gp_error_heldout") for e in eps], "n_points": [e["n_points"] for e in eps],
            "episode_s": [sum(e.get(k) or 0.0 for k in ("fit_time_s", "plan_time_s", "execute_time_s")) for e in eps],
            "first_within_1cm": first, "wall_s": wall}


def label(r: dict) -> str:
    """A variant's name in the tables and the plot."""
    return r["model"] if "uncertainty" not in r else f"{r['model']}, uncertainty {r['uncertainty']}"


def page(rows: list[dict], load: str, gp: dict | None = None) -> str:
    """The markdown page: one summary row per variant, the distance per episode, the GP's prediction cost."""
    lines = [f"UR5 with an unmodelled 1 kg payload at the tool and links 25 % heavier than its file "
             f"(`raico/problems/examples/ur5_payload.toml`); learning settings {LEARN}; uncertainty term sigma* = 0 "
             f"in standardized units; one run, load average {load}. s per episode: median fit + plan + execute; "
             "wall: the whole loop in one cache, so the babbling (and its held-out set) is paid by the first loop "
             "only.", "",
             "| model | uncertainty term | episodes | first within 1 cm | distance, first / best / last (cm) | "
             "executions ok | GP held-out error, first / last (rad/s^2) | points (last) | s per episode | wall (s) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        d = 100 * np.asarray(r["distance_m"], float)
        ok = sum(st == "ok" for st in r["status"])
        if "n_points" not in r:
            lines.append(f"| {r['model']} | - | - | - | {d[0]:.2f} | {ok} of 1 | - | - | - | {r['wall_s']:.0f} |")
            continue
        err = r["gp_error_heldout"]
        lines.append(f"| {r['model']} | {r['uncertainty']} | {len(d)} | {r['first_within_1cm'] or 'none'} | "
                     f"{d[0]:.2f} / {d.min():.2f} / {d[-1]:.2f} | {ok} of {len(d)} | {err[0]:.3g} / {err[-1]:.3g} | "
                     f"{r['n_points'][-1]} | {np.median(r['episode_s']):.1f} | {r['wall_s']:.0f} |")
    loops = [r for r in rows if "n_points" in r]
    K = max(len(r["distance_m"]) for r in loops)
    lines += ["", "Executed distance to the target per episode (cm):", "",
              "| episode | " + " | ".join(label(r) for r in loops) + " |", "|---" * (len(loops) + 1) + "|"]
    for k in range(K):
        cells = [f"{100 * r['distance_m'][k]:.2f}" if k < len(r["distance_m"]) else "" for r in loops]
        lines.append(f"| {k + 1} | " + " | ".join(cells) + " |")
    lines.append("")
    if gp:
        lines.append(f"GP mean, variance and both input gradients along a {gp['steps']}-step plan of a 7-joint arm "
                     f"({gp['inputs']} inputs, {gp['outputs']} outputs) at {gp['points']} training points: "
                     f"{gp['sparse_ms_per_output']:.2f} ms per output with the sparse GP ({gp['inducing']} inducing "
                     f"points), {gp['exact_ms_per_output']:.2f} ms with the exact GP (medians, synthetic data).")
    return "\n".join(lines)


def gp_timing(points: int = 2000, inducing: int = 200, steps: int = 100, repeats: int = 5) -> dict:
    """Milliseconds per output of the GP's mean, variance and both input gradients along a ``steps``-step plan
    of a 7-joint arm (14 state + 7 control inputs, 7 outputs) at ``points`` training points: the sparse GP
    (``inducing`` points) and the exact GP, medians of ``repeats`` calls. Synthetic smooth data (fixed
    hyperparameters: the cost does not depend on their values)."""
    from raico.plants.gp import GPModel, SparseGPModel

    rng = np.random.default_rng(0)
    d, D = 21, 7
    X = rng.standard_normal((points, d))
    Y = np.sin(X[:, :D]) + 0.3 * X[:, D:2 * D] * np.cos(X[:, 2 * D:])
    Xq = rng.standard_normal((steps, d))
    out = {"points": points, "inducing": inducing, "steps": steps, "inputs": d, "outputs": D}
    for name, model in (("sparse", SparseGPModel(X, Y, np.full((D, d), 3.0), np.ones(D), np.full(D, 1e-3),
                                                 inducing=inducing)),
                        ("exact", GPModel(X, Y, np.full((D, d), 3.0), np.ones(D), np.full(D, 1e-3)))):
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            model.predict_with_gradients(Xq)
            times.append(time.perf_counter() - t0)
        out[f"{name}_ms_per_output"] = 1e3 * float(np.median(times)) / D
    return out


def plot(rows: list[dict], path: Path) -> None:
    """Distance to the target per episode (cm, log scale) of each learning loop, the model-file plan's as a
    line, the 1 cm goal dashed; and the GP's held-out error per episode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 4.2))
    for r in rows:
        d = 100 * np.asarray(r["distance_m"], float)
        if "n_points" not in r:
            ax.axhline(d[0], color="k", lw=1.2, label=f"{r['model']} ({d[0]:.2f} cm)")
            continue
        k = np.arange(1, len(d) + 1)
        style = "o-" if r["model"] == "residual GP" else "s--"
        ax.plot(k, d, style, ms=4, label=label(r))
        ax2.plot(k, np.asarray(r["gp_error_heldout"], float), style, ms=4, label=label(r))
    ax.axhline(100 * REACH, color="g", ls="--", lw=1, label="1 cm")
    ax.set(yscale="log", xlabel="episode", ylabel="executed distance to the target (cm)",
           title="UR5, 1 kg unmodelled payload")
    ax2.set(yscale="log", xlabel="episode", ylabel="GP held-out error (rad/s^2)", title="model error")
    episode_axes((ax, ax2))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    from raico.pipeline.engine.cache import Cache

    ap = parser(__doc__.splitlines()[0], "learn_any.json")
    ap.add_argument("--episodes", type=int, default=5, help="episodes of the residual-GP loop")
    ap.add_argument("--full-episodes", type=int, default=20, help="episodes of the full-GP loop (0: skip it)")
    args = ap.parse_args()
    out = Path(args.artifacts) / "bench"
    if args.render:
        doc = json.loads((out / "learn_any.json").read_text())
        (out / "learn_any.md").write_text(page(doc["rows"], doc["load"], doc.get("gp")))
        plot(doc["rows"], out / "learn_any.png")
        return
    cache = Cache(out / "learn_any")
    rows = [model_file_row(cache)]
    for weight in SIGMA_WEIGHTS:
        rows.append(learn_row(cache, True, args.episodes, weight))
    for weight in SIGMA_WEIGHTS if args.full_episodes else ():
        rows.append(learn_row(cache, False, args.full_episodes, weight))
    gp = gp_timing()
    load = load_text()
    out.mkdir(parents=True, exist_ok=True)
    (out / "learn_any.json").write_text(json.dumps({"rows": rows, "settings": LEARN, "load": load, "gp": gp},
                                                   indent=1))
    (out / "learn_any.md").write_text(page(rows, load, gp))
    plot(rows, out / "learn_any.png")
    print(page(rows, load, gp))


if __name__ == "__main__":
    main()
