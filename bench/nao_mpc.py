"""The pushed Nao: the plan with the whole-body stabilizer against MPC above the stabilizer, stood per seed.

``python -m bench.nao_mpc [--artifacts DIR] [--seeds N]`` runs ``experiments/nao_push_mpc.toml`` (its runs
cached in ``DIR/bench/nao_mpc``) and writes ``DIR/bench/nao_mpc.json``, ``nao_mpc.md`` (the counts, the
per-seed statuses, the MPC's tick times) and ``nao_mpc.png`` (the CoG's lateral path of every run).

The experiment fixes the push (7 N at the torso along world +y from 1.8 s for 0.1 s) and the seeds (the
start postures); a run stood when the execution's ``stood`` metric holds (no fall: torso drop or tilt, a
sole lifted). Target (issue: MPC in the loop): the MPC stands in at least 9 of 10 seeds where the plan with
the stabilizer falls in more. Tick times are wall times on a shared machine (the load in the page).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENT = ROOT / "experiments" / "nao_push_mpc.toml"
TARGET_STOOD = 9
SEEN_AT = (1.75, 1.9, 2.0)   # s: before the push, at its end, 0.2 s on (the second CoG via-point)


def run_experiment(cache, seeds: int | None) -> tuple[Any, list[dict]]:
    """The experiment's runs (cached ones read back), one process: ``(experiment, rows)``."""
    from raico.pipeline.engine.executors import SerialExecutor
    from raico.pipeline.experiments import expfile

    exp = expfile.load(EXPERIMENT, [f"seeds=range({seeds})"] if seeds else [])
    rows = expfile.run(cache, exp, SerialExecutor())
    return exp, list(rows)


def per_seed(rows: list[dict]) -> dict[str, dict[int, dict]]:
    """variant -> seed -> the run's status, stood, failure time (s), its reason, MPC tick median / p99 (s),
    and the path of its execution."""
    out: dict[str, dict[int, dict]] = {}
    for r in rows:
        e = {k.removeprefix("execute."): v for k, v in r.items() if k.startswith("execute.")}
        get = e.get
        out.setdefault(r["variant"], {})[int(r["seed"])] = {
            "status": get("status"), "stood": bool(get("stood")), "failure_time": get("failure_time"),
            "reason": get("reason"), "median_tick_s": get("mpc_median_tick_s"), "p99_tick_s": get("mpc_p99_tick_s"),
            "over_period": get("mpc_over_period"), "key": get("key")}
    return out


def figure(cache_root: Path, table: dict[str, dict[int, dict]], path: Path, push: tuple[float, float]) -> None:
    """The CoG's lateral position (world y, m) over time of every run, one panel per variant; green: stood,
    red: fell (drawn to its fall); the push shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = 2 if len(table) > 2 else 1
    cols = -(-len(table) // rows)
    fig, axes = plt.subplots(rows, cols, figsize=(5.5 * cols, 3.4 * rows), sharex=True, sharey=True, squeeze=False)
    for ax, (label, seeds) in zip(axes.ravel(), table.items()):   # a row per push (the file's order)
        for _, run in sorted(seeds.items()):
            d = np.load(cache_root / "execute" / run["key"] / "rollout.npz")
            t, y = d["times"], d["cog"][:, 1]
            if not run["stood"] and run["failure_time"] is not None:
                keep = t <= run["failure_time"] + 0.1
                t, y = t[keep], y[keep]
            ax.plot(t, y, color="tab:green" if run["stood"] else "tab:red", lw=1.0, alpha=0.8)
        if "no push" not in label:
            ax.axvspan(push[0], push[0] + push[1], color="0.85", zorder=0, label="push")
            ax.legend(loc="lower left", fontsize=8)
        stood = sum(r["stood"] for r in seeds.values())
        ax.set_title(f"{label}: stood {stood} of {len(seeds)}", fontsize=10)
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    for ax in axes[:, 0]:
        ax.set_ylabel("CoG y, world (m)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def what_the_model_sees(cache_root: Path, table: dict[str, dict[int, dict]], times: tuple[float, ...]) -> dict:
    """Per variant and time (s), medians over its seeds (runs fallen by then left out; a run that stood
    and lost the plan's track stays): the CoG's forward and
    lateral position in the world, its lateral position on the planning model (the fixed-base Nao, left sole
    at the origin, at the measured joints: what the MPC's problem sees) (m), the largest joint deviation
    from the plan (rad) and the torso's tilt from upright (rad)."""
    from raico.plants.robots import shared_robot
    from raico.stages.execute.wbc import plan_cog

    fixed = shared_robot("nao")
    out: dict = {}
    for label, seeds in table.items():
        rows: dict[float, list] = {t: [] for t in times}
        for run in seeds.values():
            d = np.load(cache_root / "execute" / run["key"] / "rollout.npz")
            dt = float(d["times"][1] - d["times"][0])
            for t in times:
                k = int(round(t / dt))
                if not run["stood"] and run["failure_time"] is not None and t >= run["failure_time"]:
                    continue
                c_model = plan_cog(fixed, d["X"][k:k + 1], dt)[0][0, 1]
                dev = float(np.max(np.abs(d["X"][k, :fixed.n_q] - d["X_plan"][k, :fixed.n_q])))
                tilt = float(np.arccos(np.clip(d["torso_z"][k, 2], -1, 1)))
                rows[t].append((d["cog"][k, 0], d["cog"][k, 1], c_model, dev, tilt))
        out[label] = {t: (np.median(np.array(v), axis=0).tolist(), len(v)) if v else (None, 0) for t, v in rows.items()}
    return out


def _ms(v) -> str:
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else f"{1e3 * v:.1f}"


def markdown(table: dict[str, dict[int, dict]], push: str, load: tuple[float, float], seen: dict | None = None) -> str:
    """The page: the counts, the target's verdict, what the MPC's problem sees (``seen``:
    :func:`what_the_model_sees`), the per-seed statuses."""
    labels = list(table)
    seeds = sorted(next(iter(table.values())))
    lines = [f"The Nao pushed at the torso (`--push {push}`), seeds {seeds[0]}-{seeds[-1]} (start postures); "
             f"machine: 2 cores, 1-minute load average {load[0]:.2f} at the start, {load[1]:.2f} at the end "
             "(tick times are wall times under that load).", "",
             "| controller | stood | fell | median tick (ms) | p99 tick (ms) | ticks past the 10 ms period |",
             "|---|---|---|---|---|---|"]
    for label in labels:
        runs = table[label]
        stood = sum(r["stood"] for r in runs.values())
        med = [r["median_tick_s"] for r in runs.values() if r["median_tick_s"] is not None]
        p99 = [r["p99_tick_s"] for r in runs.values() if r["p99_tick_s"] is not None]
        over = [r["over_period"] for r in runs.values() if r["over_period"] is not None]
        lines.append(f"| {label} | {stood} | {len(runs) - stood} | {_ms(float(np.median(med)) if med else None)} | "
                     f"{_ms(float(np.median(p99)) if p99 else None)} | "
                     f"{f'{int(np.sum(over))} of {300 * len(over)}' if over else '-'} |")
    mpc = [lb for lb in labels if lb.startswith("MPC") and "no push" not in lb]
    base = [lb for lb in labels if not lb.startswith("MPC") and "no push" not in lb]
    if mpc and base:
        s_mpc = sum(r["stood"] for r in table[mpc[0]].values())
        f_base = sum(not r["stood"] for r in table[base[0]].values())
        f_mpc = len(table[mpc[0]]) - s_mpc
        met = s_mpc >= TARGET_STOOD and f_base > f_mpc
        lines += ["", f"Target: MPC stands in at least {TARGET_STOOD} of 10 and the plan with the stabilizer falls in "
                  f"more: {'met' if met else 'missed'} ({mpc[0]}: stood {s_mpc}; {base[0]}: fell {f_base}, "
                  f"{mpc[0]}: fell {f_mpc})."]
    if seen:
        lines += ["", "Before the push (1.75 s), at its end (1.9 s) and at the second via-point (2.0 s), medians over "
                  "the seeds still standing then: the CoG in the world (x forward, y lateral), its lateral position "
                  "on the planning model at the measured joints (the fixed-base Nao, left sole at the origin: what "
                  "the MPC's problem sees), the largest joint deviation from the plan and the torso's tilt:", "",
                  "| controller | t (s) | runs | CoG x (cm) | CoG y (cm) | CoG y on the model (cm) | "
                  "largest joint deviation (rad) | torso tilt (rad) |", "|---|---|---|---|---|---|---|---|"]
        for label, per_t in seen.items():
            for t, (v, n) in per_t.items():
                if v is None:
                    lines.append(f"| {label} | {t:.2f} | 0 | - | - | - | - | - |")
                    continue
                lines.append(f"| {label} | {t:.2f} | {n} | {100 * v[0]:.2f} | {100 * v[1]:.2f} | {100 * v[2]:.2f} | "
                             f"{v[3]:.2f} | {v[4]:.3f} |")
    lines += ["", "| seed | " + " | ".join(labels) + " |", "|---|" + "---|" * len(labels)]
    for s in seeds:
        cells = []
        for label in labels:
            r = table[label].get(s)
            if r is None:
                cells.append("-")
                continue
            ft = f" at {r['failure_time']:.2f} s" if r["failure_time"] is not None and not r["stood"] else ""
            cells.append(f"{'stood' if r['stood'] else 'fell'} ({r['status']}{ft})")
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    lines += ["", "![the pushed Nao's CoG](nao_mpc.png)"]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--artifacts", default="artifacts")
    ap.add_argument("--seeds", type=int, default=None, help="the first N seeds only (default: the file's)")
    args = ap.parse_args(argv)
    from raico.pipeline.engine.cache import Cache

    out = Path(args.artifacts) / "bench"
    out.mkdir(parents=True, exist_ok=True)
    start = os.getloadavg()[0]
    cache = Cache(out / "nao_mpc")
    exp, rows = run_experiment(cache, args.seeds)
    table = per_seed(list(rows))
    push = exp.base["execute"]["push"][0]
    _, _, t0, dur = push.rsplit(":", 3)
    figure(cache.root, table, out / "nao_mpc.png", (float(t0), float(dur)))
    (out / "nao_mpc.json").write_text(json.dumps({"push": push, "runs": table}, indent=2, allow_nan=True))
    seen = what_the_model_sees(cache.root, table, SEEN_AT)
    page = markdown(table, push, (start, os.getloadavg()[0]), seen)
    (out / "nao_mpc.md").write_text(page)
    sys.stdout.write(page)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
