"""Why the cart-pole loop misses the upright in its first episodes: the planner, the model or the execution.

Two measurements at planner budgets (R-AICO's iteration cap; its own stopping rule may end a plan earlier).
The control, at each of ``--budgets``: R-AICO on the exact model (the problem file's analytic dynamics, no GP), its
plan's end error and the execution's on the Drake plant: a budget at which even the exact model's plan ends
short is the planner's limit. The loop, at each of ``--loop-budgets`` (``experiments/cartpole_pilco.toml``, ``--episodes``
episodes of ``--seeds`` seeds): per episode the iterations run, the plan's end error on its own GP, the
executed end error, and the GP's error of the pole's acceleration along the plan (its mean against the exact
model's at the planned states and controls): a plan that ends upright on its GP and an execution that does
not, with a large error along the plan, is the model's miss. Writes ``artifacts/bench/cartpole_pilco_diagnosis.md``.

    python -m bench.cartpole_pilco_diagnosis [--seeds 3] [--episodes 3] [--budgets 20,50,100,150] [--loop-budgets 20,150]
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from bench.cartpole_pilco import settings
from bench.learning_common import load_text, parser

PROBLEM = Path(__file__).resolve().parents[1] / "raico" / "problems" / "cartpole_swing-up.toml"


def wrap(a: float) -> float:
    """An angle's distance from upright (rad, wrapped to [0, pi])."""
    return float(abs((a - np.pi + np.pi) % (2 * np.pi) - np.pi))


def exact_model(cache, budget: int) -> dict:
    """R-AICO (the loop's alpha and schedule) on the exact model at ``budget``: iterations, end errors planned and executed."""
    from raico.pipeline.engine.runner import run
    from raico.stages.execute.config import ExecuteConfig
    from raico.stages.learn import LearnConfig
    from raico.stages.plan.stage import PlanConfig

    s = settings()
    problem = LearnConfig(problem=str(PROBLEM)).normalized().problem
    p = run(cache, "plan", PlanConfig(problem=problem, dynamics="analytic", solver="raico", alpha=s["alpha"],
                                      alpha_schedule=s["alpha_schedule"], iterations=budget), record=False)
    e = run(cache, "execute", ExecuteConfig(plan=p.key), record=False)
    z = np.load(Path(p.path) / "plan.npz")
    X = np.load(Path(e.path) / "rollout.npz")["X"]
    return {"budget": budget, "iterations": len(z["costs"]), "cost": float(z["costs"][-1]),
            "planned": wrap(z["X"][-1, 1]), "executed": wrap(X[-1, 1]), "status": e.status}


def loop(cache, budget: int, seed: int, episodes: int) -> list[dict]:
    """The loop at ``budget``: per episode iterations, planned and executed end errors, the GP's pole error along the plan."""
    from raico.pipeline.engine.runner import run
    from raico.stages.learn import LearnConfig, Predictor, true_accelerations

    cfg = LearnConfig(**{**settings(), "episodes": episodes, "seed": seed, "iterations": budget}).normalized()
    out = run(cache, "learn", cfg, record=False)
    robot = cfg.robots()[0]
    rows = []
    for e in json.loads((Path(out.path) / "episodes.json").read_text())["episodes"]:
        z = np.load(cache.root / "plan" / e["plan"] / "plan.npz")
        X, U = z["X"][:-1], z["U"]
        pred = Predictor(dict(np.load(cache.root / "fit" / e["fit"] / "model.npz")), robot).predict_mean(np.hstack([X, U]))
        true = true_accelerations(robot, float(z["times"][1] - z["times"][0]), X, U)
        rows.append({"episode": e["episode"], "iterations": len(z["costs"]), "planned": wrap(z["X"][-1, 1]),
                     "executed": e["task_error"], "speed": e["task"].get("speed"), "achieved": e["achieved"],
                     "gp_pole_error": float(np.sqrt(np.mean((pred[:, 1] - true[:, 1]) ** 2))),
                     "pole_acc_rms": float(np.sqrt(np.mean(true[:, 1] ** 2))),
                     "random": bool(e.get("random_seconds"))})
    return rows


def main() -> None:
    from raico.pipeline.engine.cache import Cache

    ap = parser(__doc__.splitlines()[0], "cartpole_pilco_diagnosis.json")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--episodes", type=int, default=3)
    ap.add_argument("--budgets", default="20,50,100,150")
    ap.add_argument("--loop-budgets", default="20,150")
    args = ap.parse_args()
    out = Path(args.artifacts) / "bench"
    cache = Cache(out / "cartpole_pilco")       # the bench's cache: its runs at the experiment's budget are reused
    budgets = [int(b) for b in args.budgets.split(",")]
    control = [exact_model(cache, b) for b in budgets]
    lines = [f"Cart-pole loop diagnosis (`python -m bench.cartpole_pilco_diagnosis`); load average {load_text()}.", "",
             "R-AICO on the exact model (no GP), end error from upright (rad):", "",
             "| iteration cap | iterations run | final cost | planned end error | executed end error | execution |",
             "|---|---|---|---|---|---|"]
    lines += [f"| {c['budget']} | {c['iterations']} | {c['cost']:.4g} | {c['planned']:.3g} | {c['executed']:.3g} | "
              f"{c['status']} |" for c in control]
    lines += ["", "The loop on its GP, per episode (end errors in rad; the GP's pole acceleration error along the "
              "plan against the exact model's, and the exact pole acceleration's RMS along the plan, rad/s^2):", "",
              "| iteration cap | seed | episode | iterations run | planned end error (on its GP) | executed end error "
              "| end speed (rad/s) | GP pole error along the plan | pole acceleration RMS | random episode after |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for b in [int(b) for b in args.loop_budgets.split(",")]:
        for seed in range(args.seeds):
            for r in loop(cache, b, seed, args.episodes):
                lines.append(f"| {b} | {seed} | {r['episode']} | {r['iterations']} | {r['planned']:.3g} | "
                             f"{r['executed']:.3g} | {r['speed']:.2g} | {r['gp_pole_error']:.3g} | "
                             f"{r['pole_acc_rms']:.3g} | {'yes' if r['random'] else ''} |")
            print(f"budget {b} seed {seed} done", flush=True)
    out.mkdir(parents=True, exist_ok=True)
    (out / "cartpole_pilco_diagnosis.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
